#!/usr/bin/env python3
"""Is a change of setting real? Paired comparison of `b2tf bench estimate --per-instance` runs.

    tools/compare_runs.py BEFORE.csv AFTER.csv [BEFORE2.csv AFTER2.csv ...] [--setting "with RRC"]

Each pair is the same scenes (same seed and scene options) estimated before and after a
change. Every instance is right (MSSD < 0.1·d) or not in each run; the instances right in
one run only are the discordant pairs, and under "the change does nothing" each is as
likely to fall either way. The exact two-sided binomial (McNemar) p-value over the pooled
discordant pairs says how often chance alone would split them at least that unevenly.

Why it matters here: the estimate of an instance can turn on near-ties, and `bench
estimate --stability` finds verdicts that flip when the mask loses one outline pixel. A
gain of one or two instances among a handful of discordant pairs is what such flips give
by themselves.

`--self-test` checks the statistics and the pairing on built-in cases and exits.
"""

import argparse
import csv
import math
import sys


def load(path, setting):
    """(image, obj_id, occurrence) -> right? for the rows of `setting`."""
    out, seen = {}, {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row["setting"] != setting:
                continue
            key = (row["image"], row["obj_id"])
            # Two instances of one object in one image stay apart by their order.
            n = seen.get(key, 0)
            seen[key] = n + 1
            mssd = row["mssd_over_diameter"]
            out[key + (n,)] = bool(mssd) and float(mssd) < 0.1
    if not out:
        raise SystemExit(f"{path}: no rows of setting {setting!r}")
    return out


def mcnemar_p(gained, lost):
    """Exact two-sided binomial p-value of `gained` against `lost` discordant pairs."""
    n = gained + lost
    if n == 0:
        return 1.0
    k = min(gained, lost)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def compare(pairs):
    """Totals over (before, after) dicts of the same instances."""
    t = {"instances": 0, "before": 0, "after": 0, "gained": 0, "lost": 0}
    for before, after in pairs:
        if before.keys() != after.keys():
            only = sorted(before.keys() ^ after.keys())[:3]
            raise SystemExit(f"the runs are not of the same instances (e.g. {only}): same seed and scene options?")
        for k, b in before.items():
            a = after[k]
            t["instances"] += 1
            t["before"] += b
            t["after"] += a
            t["gained"] += a and not b
            t["lost"] += b and not a
    t["p"] = mcnemar_p(t["gained"], t["lost"])
    return t


def self_test():
    assert mcnemar_p(0, 0) == 1.0
    assert abs(mcnemar_p(0, 6) - 0.03125) < 1e-12  # 2 · 2⁻⁶
    assert abs(mcnemar_p(6, 0) - 0.03125) < 1e-12
    assert abs(mcnemar_p(2, 3) - 1.0) < 1e-12
    assert abs(mcnemar_p(1, 9) - 2 * 11 / 1024) < 1e-12
    before = {("0", "1", 0): True, ("0", "2", 0): False, ("1", "1", 0): True}
    after = {("0", "1", 0): False, ("0", "2", 0): True, ("1", "1", 0): True}
    t = compare([(before, after)])
    assert (t["instances"], t["before"], t["after"], t["gained"], t["lost"]) == (3, 2, 2, 1, 1), t
    try:
        compare([(before, {("0", "1", 0): True})])
    except SystemExit as e:
        assert "not of the same instances" in str(e)
    else:
        raise AssertionError("mismatched runs were compared")
    # Reading a file: only the asked setting, a row without a pose is wrong, and two
    # instances of one object in one image stay apart.
    import tempfile

    header = "image,obj_id,setting,size_px,visible,found,rot_err_deg,trans_err_mm,depth_err_mm,mssd_over_diameter\n"
    rows = ["0,3,with RRC,50,1,1,1,1,1,0.05", "0,3,with RRC,50,1,1,1,1,1,0.2", "0,3,without RRC,50,1,1,1,1,1,0.05", "1,4,with RRC,50,1,0,,,,"]
    with tempfile.NamedTemporaryFile("w", suffix=".csv") as f:
        f.write(header + "\n".join(rows) + "\n")
        f.flush()
        assert load(f.name, "with RRC") == {("0", "3", 0): True, ("0", "3", 1): False, ("1", "4", 0): False}
        try:
            load(f.name, "no such setting")
        except SystemExit as e:
            assert "no rows of setting" in str(e)
        else:
            raise AssertionError("a file without the setting's rows was read")
    print("compare_runs self-test: ok")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", help="BEFORE.csv AFTER.csv, repeated per seed")
    ap.add_argument("--setting", default="with RRC")
    ap.add_argument("--self-test", action="store_true")
    a = ap.parse_args()
    if a.self_test:
        return self_test()
    if not a.runs or len(a.runs) % 2:
        ap.error("give the runs in pairs: BEFORE.csv AFTER.csv [...]")
    pairs = [(load(a.runs[i], a.setting), load(a.runs[i + 1], a.setting)) for i in range(0, len(a.runs), 2)]
    t = compare(pairs)
    n = t["instances"]
    print(
        f"{n} instances in {len(pairs)} pair(s) of runs: right before {t['before']} ({100 * t['before'] / n:.1f} %), "
        f"after {t['after']} ({100 * t['after'] / n:.1f} %); gained {t['gained']}, lost {t['lost']}; "
        f"exact McNemar p = {t['p']:.3f}"
    )


if __name__ == "__main__":
    sys.exit(main())
