"""Records this machine's CPU where the golden-hash test passes: ``results/benchmarks/reproducibility.json``.

    python benchmarks/reproducibility.py [--slow]

Runs ``tests/test_golden_hashes.py`` and ``tests/test_isa_caps.py`` (the pinned numeric environment's golden
hashes of a short training of every agent and a short evaluation of every controller, and the instruction-set caps;
``--slow`` adds the slow caps)
on this machine, and, if it passed, adds or updates the entry of this CPU model under ``golden_hash_test``:
model, vendor, family/model/stepping, its flags, the commit, the tests that ran and passed, the date. An entry is
keyed by (model name, flags): the same model name with other flags (another hypervisor's CPU mask) is another
entry. A failing run records nothing and exits 1: see the test's docstring for what to do.

Each entry names the golden set it passed (``golden_set``: ``shared`` or the vendor's own, tests/golden_sets.py) and
that set's digest (``set_digest``), so the entries at the current set can be told from older ones.

``--golden-set``: after writing a golden set into tests/data/golden_hashes.json (from ``python -m
pipelines.numerics_probe`` and ``python -m pipelines.numerics_fingerprint``), record under ``golden_sets`` that this
CPU model made it, at this commit; then run the tests as above.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import subprocess
import sys
from pathlib import Path

from srmpc.numerics import cpuinfo

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script, this folder is first on the path: the repository's tests too
    sys.path.insert(0, str(ROOT))

from tests.golden_sets import SHARED, set_digest, set_name, this_vendors_set, vendor_sets  # noqa: E402

OUTPUT = ROOT / "results" / "benchmarks" / "reproducibility.json"
TESTS = ("tests/test_golden_hashes.py", "tests/test_numerics_fingerprint.py", "tests/test_mkl_off_the_path.py",
         "tests/test_isa_caps.py")


def this_commit() -> str:
    """HEAD's hash, with ``+uncommitted`` when tracked files differ from it."""
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip())
    return commit + ("+uncommitted" if dirty else "")


def golden_set() -> tuple[str, str]:
    """The golden set this CPU is compared with (``shared`` or its vendor_id) and that set's digest."""
    return set_name(), set_digest(this_vendors_set())


def record_golden_set(out: Path) -> None:
    """``golden_sets[name]``: the CPU model (vendor, family/model/stepping) and commit that made the set this CPU is
    compared with."""
    info = cpuinfo()
    record = json.loads(out.read_text()) if out.exists() else {}
    name, digest = golden_set()
    current = {SHARED, *vendor_sets()}
    record["golden_sets"] = {key: entry for key, entry in record.get("golden_sets", {}).items() if key in current}
    record["golden_sets"][name] = {
        "model": info.get("model name"), "vendor": info.get("vendor_id"), "set_digest": digest,
        "family_model_stepping": [info.get("cpu family"), info.get("model"), info.get("stepping")],
        "commit": this_commit(), "date": datetime.date.today().isoformat()}
    out.write_text(json.dumps(record, indent=2) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--slow", action="store_true", help="also the slow caps (NUMBA_CPU_NAME, ...)")
    parser.add_argument("--golden-set", action="store_true",
                        help="record this CPU as the maker of its vendor's golden set (golden_sets), then test")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    if args.golden_set:
        record_golden_set(args.out)
    command = [sys.executable, "-m", "pytest", *TESTS, "-p", "no:xdist", "-q", "-p", "no:cacheprovider"]
    if args.slow:
        command += ["-m", ""]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    print(done.stdout[-3000:], done.stderr[-2000:], sep="\n")
    summary = re.search(r"(\d+) passed", done.stdout)
    if done.returncode != 0 or summary is None:
        sys.exit(f"{' and '.join(TESTS)} did not pass on this CPU: nothing recorded")
    info = cpuinfo()
    entry = {
        "model": info.get("model name"), "vendor": info.get("vendor_id"),
        "family_model_stepping": [info.get("cpu family"), info.get("model"), info.get("stepping")],
        "flags": sorted(info.get("flags", "").split()),
        "commit": this_commit(), "golden_set": golden_set()[0], "set_digest": golden_set()[1],
        "tests_passed": int(summary.group(1)),
        "slow_caps": args.slow, "date": datetime.date.today().isoformat(),
    }
    record = json.loads(args.out.read_text()) if args.out.exists() else {}
    entries = [e for e in record.get("golden_hash_test", [])
               if (e["model"], e["flags"]) != (entry["model"], entry["flags"])]
    record["golden_hash_test"] = [*entries, entry]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"recorded {entry['model']} ({entry['vendor']}) at {entry['commit'][:12]} in {args.out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
