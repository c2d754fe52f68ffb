#!/usr/bin/env python3
"""The import graph of the Rust crate's files, and its circles.

Each file under src/ is a node (`mod.rs` stands for its folder, `lib.rs` / `main.rs` for
the crate). An edge A → B says that A's code (outside its `#[cfg(test)]` module) names
something of B through `crate::…`, `super::…` or `self::…`. A folder's face (its `mod.rs`)
declaring and re-exporting its own files is the folder's shape, not an import, so edges
from a folder's face to the files inside it are left out; everything else counts.

    tools/import_circles.py [--src src] [--edges] [--house]
    tools/import_circles.py --self-test    # three small trees: a file circle, a circle of
                                           # parts through a test file, none

Prints every circle (a strongly connected set of two or more files, with the edges that
close it) and exits 1 if there is one. The same for the top-level parts (a folder under
src/ or a file beside lib.rs): two parts that import each other, even through test files,
are a circle of the house, and an arrow between them runs up a floor. `--edges` prints
the file graph too; `--house` prints the parts floor by floor (a part's floor is one
above the highest part it imports), the drawing in docs/development.md.
"""

import argparse
import re
import sys
from pathlib import Path

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


def module_of(path: Path, src: Path) -> tuple[str, ...]:
    parts = path.relative_to(src).with_suffix("").parts
    # A folder's mod.rs is the folder; lib.rs and main.rs are the crate.
    if parts[-1] == "mod" or parts in (("lib",), ("main",)):
        parts = parts[:-1]
    return parts


def strip_tests(text: str) -> str:
    """The file without its test module (`#[cfg(test)] mod …` to the end of that block)."""
    out, i = [], 0
    for m in re.finditer(r"#\[cfg\(test\)\]\s*(pub(\([^)]*\))?\s+)?mod\s+" + IDENT + r"\s*\{", text):
        if m.start() < i:
            continue
        depth, j = 1, m.end()
        while j < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        out.append(text[i : m.start()])
        i = j
    out.append(text[i:])
    return "".join(out)


def strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return re.sub(r"//[^\n]*", "", text)


def expand_use(tree: str) -> list[str]:
    """`a::{b, c::{d, e}}` → a::b, a::c::d, a::c::e (aliases and globs kept as paths)."""
    tree = re.sub(r"\s+", "", tree)
    m = re.match(r"^(.*?)\{(.*)\}$", tree)
    if not m:
        return [re.sub(r"as" + IDENT + "$", "", tree)]
    prefix, inner = m.group(1), m.group(2)
    items, depth, cur = [], 0, ""
    for ch in inner:
        if ch == "," and depth == 0:
            items.append(cur)
            cur = ""
            continue
        depth += {"{": 1, "}": -1}.get(ch, 0)
        cur += ch
    items.append(cur)
    return [p for item in items if item for p in expand_use(prefix + item)]


def paths_in(text: str) -> list[str]:
    paths = []
    for m in re.finditer(r"\buse\s+([^;]+);", text):
        paths.extend(expand_use(m.group(1)))
    body = re.sub(r"\buse\s+[^;]+;", "", text)
    paths.extend(m.group(0) for m in re.finditer(r"\b(?:crate|super|self)(?:::" + IDENT + r")+", body))
    return paths


def resolve(path: str, here: tuple[str, ...], is_face: bool, modules: set[tuple[str, ...]]) -> tuple[str, ...] | None:
    parts = path.split("::")
    # The module the path starts from: a face's `self` is its folder; a file's `super`
    # is its folder, a face's `super` the folder above.
    folder = here if is_face else here[:-1]
    base: tuple[str, ...]
    if parts[0] == "crate":
        base, rest = (), parts[1:]
    elif parts[0] == "self":
        base, rest = here, parts[1:]
    elif parts[0] == "super":
        base, rest = folder, parts[1:]
        while rest and rest[0] == "super":
            base, rest = base[:-1], rest[1:]
    else:
        return None
    target = base
    for p in rest:
        if target + (p,) in modules:
            target = target + (p,)
        else:
            break
    return target


def graph(src: Path) -> dict[tuple[str, ...], dict[tuple[str, ...], str]]:
    files = list(src.rglob("*.rs"))
    modules = {module_of(p, src) for p in files}
    edges: dict[tuple[str, ...], dict[tuple[str, ...], str]] = {}
    for p in files:
        here = module_of(p, src)
        is_face = p.name in ("mod.rs", "lib.rs", "main.rs")
        text = strip_tests(strip_comments(p.read_text()))
        out = edges.setdefault(here, {})
        for path in paths_in(text):
            t = resolve(path, here, is_face, modules)
            if t is None or t == here:
                continue
            # A face naming what lies inside its own folder is the folder's shape.
            if is_face and t[: len(here)] == here:
                continue
            out.setdefault(t, path)
    return edges


def circles(edges):
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def parts_graph(edges):
    """The edges between top-level parts, each with one file edge that makes it."""
    out: dict[tuple[str, ...], dict[tuple[str, ...], str]] = {}
    for v, targets in edges.items():
        pv = v[:1]
        out.setdefault(pv, {})
        for w, via in targets.items():
            pw = w[:1]
            if pw != pv:
                out[pv].setdefault(pw, f"{name(v)} -> {name(w)}: {via}")
    return out


def floors(parts) -> list[list[tuple[str, ...]]]:
    """Parts by floor: the ground floor imports no other part."""
    floor: dict[tuple[str, ...], int] = {}

    def of(v, seen=()):
        if v not in floor:
            below = [of(w, seen + (v,)) for w in parts.get(v, {}) if w not in seen]
            floor[v] = 1 + max(below, default=-1)
        return floor[v]

    for v in parts:
        of(v)
    out: list[list[tuple[str, ...]]] = [[] for _ in range(max(floor.values(), default=-1) + 1)]
    for v, f in floor.items():
        out[f].append(v)
    return [sorted(f) for f in out]


def name(m: tuple[str, ...]) -> str:
    return "/".join(m) or "(crate)"


def print_circles(title: str, found, edges) -> None:
    """Each circle's members, then the edges that close it (`edges[v][w]`: how to say v → w)."""
    for comp in found:
        members = set(comp)
        print(f"{title} {len(comp)}: " + ", ".join(name(m) for m in comp))
        for v in comp:
            for w, said in sorted(edges[v].items()):
                if w in members:
                    print(f"    {said}")


def self_test() -> int:
    """A crate whose parts a and b import each other, first file to file, then only through
    a test file of b (a circle of the house, not of files), then only one way."""
    import tempfile

    def tree(files: dict[str, str]) -> Path:
        root = Path(tempfile.mkdtemp()) / "src"
        for rel, text in files.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_text(text)
        return root

    base = {"lib.rs": "pub mod a;\npub mod b;\n", "a/mod.rs": "pub mod x;\n", "a/x.rs": "use crate::b::y::Y;\npub struct X;\n"}
    files = tree({**base, "b/mod.rs": "pub mod y;\n", "b/y.rs": "use crate::a::x::X;\npub struct Y;\n"})
    assert circles(graph(files)) == [[("a", "x"), ("b", "y")]], circles(graph(files))
    through_test = tree({**base, "b/mod.rs": "pub mod y;\n#[cfg(test)]\nmod y_tests;\n", "b/y.rs": "pub struct Y;\n", "b/y_tests.rs": "use crate::a::x::X;\n"})
    edges = graph(through_test)
    assert circles(edges) == [] and circles(parts_graph(edges)) == [[("a",), ("b",)]], circles(parts_graph(edges))
    one_way = tree({**base, "b/mod.rs": "pub mod y;\n", "b/y.rs": "pub struct Y;\n"})
    parts = parts_graph(graph(one_way))
    assert circles(parts) == [] and floors(parts) == [[(), ("b",)], [("a",)]], floors(parts)
    print("import_circles self-test: ok")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--src", default="src", type=Path)
    ap.add_argument("--edges", action="store_true")
    ap.add_argument("--house", action="store_true")
    ap.add_argument("--self-test", action="store_true")
    a = ap.parse_args()
    if a.self_test:
        return self_test()
    edges = graph(a.src)
    if a.edges:
        for v in sorted(edges):
            for w, via in sorted(edges[v].items()):
                print(f"{name(v)} -> {name(w)}  ({via})")
    found = circles(edges)
    print_circles("circle of", found, {v: {w: f"{name(v)} -> {name(w)}  ({via})" for w, via in t.items()} for v, t in edges.items()})
    print(f"{len(edges)} files, {sum(len(e) for e in edges.values())} edges, {len(found)} circles")
    parts = parts_graph(edges)
    house = circles(parts)
    print_circles("circle of the house,", house, parts)
    if a.house and not house:
        for i, f in reversed(list(enumerate(floors(parts)))):
            print(f"floor {i}: " + " ".join(name(m) for m in f))
    print(f"{len(parts)} parts, {sum(len(e) for e in parts.values())} arrows between them, {len(house)} circles")
    return 1 if found or house else 0


if __name__ == "__main__":
    sys.exit(main())
