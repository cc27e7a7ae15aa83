"""Turn pip's installation report into ``requirements.lock``: ``python .ci/lock.py REPORT LOCK COMMAND``.

REPORT is what ``pip install --dry-run --ignore-installed --report REPORT -e '.[dev,nmpc]'`` wrote (``make lock``
runs both); COMMAND is that pip command, quoted into the header. The lock holds every package of the resolution
except the project itself, sorted by normalized name, each as ``name==version`` with the sha256 of the file pip
chose, in the format ``pip install --require-hashes --no-deps -r requirements.lock`` checks. Standard library only.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

PROJECT = "srmpc"
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
"""Where torch's ``+cpu`` wheels live outside this workplace (PyPI has only the CUDA build)."""


def normalize(name: str) -> str:
    """PEP 503's normalized name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def locked_packages(report: dict) -> list[tuple[str, str, list[str]]]:
    """(name, version, sha256 hashes) of every package the report installs, the project excepted, sorted."""
    packages = {}
    for item in report["install"]:
        name, version = normalize(item["metadata"]["name"]), item["metadata"]["version"]
        if name == PROJECT:
            continue
        hashes = item["download_info"].get("archive_info", {}).get("hashes", {})
        if "sha256" not in hashes:
            raise SystemExit(f"{name}=={version}: pip's report gives no sha256 ({item['download_info']['url']})")
        if name in packages:
            raise SystemExit(f"{name}: twice in pip's report ({packages[name][0]}, {version})")
        packages[name] = (version, [hashes["sha256"]])
    return [(name, version, hashes) for name, (version, hashes) in sorted(packages.items())]


def lock_text(report: dict, command: str) -> str:
    environment = report["environment"]
    header = [
        "# Every package `pip install -e '.[dev,nmpc]'` installs (the whole closure of pyproject.toml's dependencies),",
        "# at exact versions, with the sha256 of each file; `make install` installs them with",
        "# `pip install --require-hashes --no-deps -r requirements.lock`. Written by `make lock` (do not edit), from",
        f"#   {command}",
        f"# resolved by pip {report['pip_version']} on {environment['platform_python_implementation']} "
        f"{environment['python_full_version']}, {environment['sys_platform']} {environment['platform_machine']}: "
        "the hashes are of the wheels pip chose there.",
        "# torch is the CPU build (+cpu) from PyTorch's index below; PyPI's torch of that version is a CUDA build.",
        f"--extra-index-url {TORCH_CPU_INDEX}",
        "",
    ]
    body = []
    for name, version, hashes in locked_packages(report):
        body.append(" \\\n".join([f"{name}=={version}", *(f"    --hash=sha256:{digest}" for digest in hashes)]))
    return "\n".join(header + body) + "\n"


def main(argv: list[str]) -> None:
    report_path, lock_path, command = argv
    report = json.loads(Path(report_path).read_text())
    Path(lock_path).write_text(lock_text(report, command))
    print(f"{lock_path}: {len(locked_packages(report))} packages, pip {report['pip_version']}")


if __name__ == "__main__":
    main(sys.argv[1:])
