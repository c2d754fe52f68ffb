"""Checks that the `b2tf` commands the README and the docs show run as written: every
command line in a fenced shell block, and every inline `b2tf …` code span, must name an
existing subcommand and only flags that subcommand takes (read from its `--help`), and
the repository scripts and tools the docs tell people to run must exist.

Placeholders (`MESH`, `photo.png`, `[ID ...]`) are not run: this catches the doc rot that
happens (a renamed flag, a removed subcommand, a moved script); the commands themselves run
in scripts/run.sh, the CLI tests and the browser test.

Usage: python3 tools/check_doc_commands.py [B2TF_BINARY]   (default: target/debug/b2tf)
"""

from __future__ import annotations

import re
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", REPO / "DESIGN.md", REPO / "clients/python/README.md", *sorted((REPO / "docs").rglob("*.md"))]
# The CLI as a command's first word.
CLI = re.compile(r"^(?:\$B2TF|b2tf|(?:\./)?target/(?:release|debug)/b2tf)$")
# Repository scripts and tools people are told to run.
SCRIPT = re.compile(r"^(?:\./)?((?:scripts|tools|fuzz|deploy|console|clients/python/scripts)/[\w./-]+\.(?:sh|py))$")
# Words before the command itself: VAR=value, and wrappers.
PREFIX = re.compile(r"^(?:\w+=\S*\s+|nice\s+-n\s*-?\d+\s+|timeout\s+\d+\s+|sudo\s+|exec\s+)+")


def run_help(binary: str, path: tuple) -> str:
    p = subprocess.run([binary, *path, "--help"], capture_output=True, text=True)
    return p.stdout if p.returncode == 0 else ""


@lru_cache(maxsize=None)
def subcommands(binary: str, path: tuple) -> frozenset:
    """The subcommands `b2tf PATH --help` lists."""
    text = run_help(binary, path)
    names, listing = set(), False
    for line in text.splitlines():
        if line.strip() == "Commands:":
            listing = True
        elif listing and re.match(r"^  \S", line):
            names.add(line.split()[0])
        elif listing and line.strip() and not line.startswith(" "):
            listing = False
    return frozenset(names - {"help"})


@lru_cache(maxsize=None)
def flags(binary: str, path: tuple) -> frozenset:
    return frozenset(re.findall(r"--[a-z][a-z0-9-]*", run_help(binary, path)))


def commands(md: Path):
    """(line number, command words) of every command the file shows: lines of fenced shell
    blocks (continuations joined, comments dropped) and inline code spans, without the
    VAR=value and wrapper words before the command."""
    lines = md.read_text().splitlines()
    fence, i = None, 0
    while i < len(lines):
        line = lines[i]
        m = re.match(r"^\s*```(\w*)", line)
        if m:
            fence = None if fence is not None else m.group(1)
            i += 1
            continue
        found = []
        if fence in ("sh", "bash", "shell", ""):
            start, text = i + 1, line.strip()
            while text.endswith("\\") and i + 1 < len(lines):
                i += 1
                text = text[:-1] + " " + lines[i].strip()
            found.append((start, re.sub(r"(^|\s+)#.*$", "", text)))
        elif fence is None:
            found += [(i + 1, span) for span in re.findall(r"`([^`]+)`", line)]
        for at, text in found:
            words = PREFIX.sub("", text.strip()).split()
            if words and words[0] in ("bash", "sh", "python3", "python") and len(words) > 1:
                words = words[1:]
            if words:
                yield at, words
        i += 1


def check(binary: str) -> list:
    problems = []
    top = subcommands(binary, ())
    if not top:
        return [f"{binary} --help lists no subcommands: is it built?"]
    for md in DOCS:
        rel = md.relative_to(REPO)
        for line, words in commands(md):
            script = SCRIPT.match(words[0])
            if script and not (REPO / script.group(1)).exists():
                problems.append(f"{rel}:{line}: {script.group(1)} does not exist")
            if not CLI.match(words[0]) or len(words) == 1:
                continue  # not the CLI, or the binary named alone
            args, path = words[1:], ()
            while args and args[0] in subcommands(binary, path):
                path, args = path + (args[0],), args[1:]
            if not path:
                problems.append(f"{rel}:{line}: `{' '.join(words)[:70]}`: no such subcommand {args[0]!r}")
                continue
            known = flags(binary, path)
            for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", " ".join(args)):
                if flag not in known:
                    problems.append(f"{rel}:{line}: `b2tf {' '.join(path)}` takes no {flag}")
    return problems


def main() -> None:
    binary = sys.argv[1] if len(sys.argv) > 1 else str(REPO / "target/debug/b2tf")
    problems = check(binary)
    count = sum(1 for md in DOCS for _, w in commands(md) if CLI.match(w[0]) and len(w) > 1)
    if problems:
        print("\n".join(problems))
        raise SystemExit(f"{len(problems)} problem(s) in the docs' commands")
    print(f"{count} b2tf commands in {len(DOCS)} docs name existing subcommands and flags; the scripts they name exist")


if __name__ == "__main__":
    main()
