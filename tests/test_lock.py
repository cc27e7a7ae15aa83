"""``requirements.lock`` agrees with ``pyproject.toml`` and with the installed environment.

The lock (written by ``make lock``, installed by ``make install`` with ``pip install --require-hashes --no-deps``)
locks each package once, with a sha256; admits every requirement of ``[project].dependencies`` and of the ``dev``
and ``nmpc`` extras; and is their closure: every ``Requires-Dist`` of a locked package that applies here (its
marker true for this Python and platform, ``extra == ...`` only for extras someone requests) is locked at a version
it admits, and every locked package is reached so. The ``Requires-Dist`` come from the installed distributions
(``make install`` installs the lock), so a package installed at another version than locked is named, one line.
Every failure names the package. The checkers are plain functions; the last test feeds them broken input.
"""

from __future__ import annotations

import importlib.metadata
import re
import tomllib
from collections.abc import Callable
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements.lock"
PYPROJECT = ROOT / "pyproject.toml"
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
EXTRAS = ("dev", "nmpc")
"""The extras of ``pyproject.toml`` that ``make lock`` resolves."""

Lock = dict[str, tuple[str, list[str]]]
"""{normalized name: (version, sha256 hashes)}."""


def parse_lock(text: str) -> tuple[Lock, list[str], list[str]]:
    """(packages, option lines such as ``--extra-index-url``, problems) of a lock in pip's requirements format."""
    packages: Lock = {}
    options, problems = [], []
    logical = re.sub(r"\\\n", " ", text)  # pip joins lines ending in a backslash
    for line in logical.splitlines():
        line = line.split(" #", 1)[0].strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("-"):
            options.append(line)
            continue
        words = line.split()
        match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)", words[0])
        if not match:
            problems.append(f"{words[0]}: not name==version")
            continue
        name, version = canonicalize_name(match[1]), match[2]
        hashes = [w.removeprefix("--hash=sha256:") for w in words[1:] if w.startswith("--hash=sha256:")]
        others = [w for w in words[1:] if not w.startswith("--hash=sha256:")]
        if others:
            problems.append(f"{name}: unexpected {' '.join(others)}")
        if not hashes or not all(re.fullmatch(r"[0-9a-f]{64}", h) for h in hashes):
            problems.append(f"{name}=={version}: no sha256 hash (`--hash=sha256:<64 hex digits>`)")
        if name in packages:
            problems.append(f"{name}: locked twice ({packages[name][0]} and {version})")
        packages[name] = (version, hashes)
    return packages, options, problems


def pyproject_requirements(pyproject: dict) -> list[Requirement]:
    """``[project].dependencies`` and the requirements of the extras ``make lock`` resolves."""
    project = pyproject["project"]
    texts = project["dependencies"] + [r for extra in EXTRAS for r in project["optional-dependencies"][extra]]
    return [Requirement(text) for text in texts]


def _admits(requirement: Requirement, version: str) -> bool:
    return requirement.specifier.contains(Version(version), prereleases=True)


def _applies(requirement: Requirement, extra: str) -> bool:
    return requirement.marker is None or requirement.marker.evaluate({**default_environment(), "extra": extra})


def pyproject_problems(packages: Lock, requirements: list[Requirement]) -> list[str]:
    """One line per requirement of pyproject.toml the lock lacks or locks at a version it does not admit."""
    problems = []
    for requirement in filter(lambda r: _applies(r, ""), requirements):
        name = canonicalize_name(requirement.name)
        if name not in packages:
            problems.append(f"{name}: pyproject.toml requires {requirement}, not locked (make lock)")
        elif not _admits(requirement, packages[name][0]):
            problems.append(f"{name}: locked {packages[name][0]}, pyproject.toml requires {requirement} (make lock)")
    return problems


def closure_problems(packages: Lock, roots: list[Requirement], requires: Callable[[str], list[str]]) -> list[str]:
    """One line per requirement reached from ``roots`` that the lock lacks or does not admit, and per locked package
    nothing reaches. ``requires(name)``: the ``Requires-Dist`` of the locked package ``name``."""
    problems = []
    reached, walked = set(), set()
    queue = [(requirement, "pyproject.toml") for requirement in roots if _applies(requirement, "")]
    while queue:
        requirement, required_by = queue.pop()
        name = canonicalize_name(requirement.name)
        if name not in packages:
            problems.append(f"{name}: {required_by} requires {requirement}, not locked (make lock)")
            continue
        reached.add(name)
        if not _admits(requirement, packages[name][0]):
            problems.append(f"{name}: locked {packages[name][0]}, {required_by} requires {requirement} (make lock)")
        for extra in {"", *(canonicalize_name(e) for e in requirement.extras)}:
            if (name, extra) in walked:
                continue
            walked.add((name, extra))
            by = f"{name}[{extra}]" if extra else name
            queue += [(dep, by) for dep in map(Requirement, requires(name)) if _applies(dep, extra)]
    problems += [f"{name}: locked, but nothing of pyproject.toml's closure requires it (make lock)"
                 for name in sorted(set(packages) - reached)]
    return list(dict.fromkeys(problems))


def installed_problems(packages: Lock, installed: Callable[[str], str | None]) -> list[str]:
    """One line per locked package not installed at its locked version; ``installed(name)``: its version or None."""
    problems = []
    for name, (version, _) in sorted(packages.items()):
        found = installed(name)
        if found is None:
            problems.append(f"{name}: locked {version}, not installed (make install)")
        elif Version(found) != Version(version):
            problems.append(f"{name}: installed {found}, locked {version} (make install)")
    return problems


def _installed_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def _installed_requires(name: str) -> list[str]:
    try:
        return importlib.metadata.distribution(name).requires or []
    except importlib.metadata.PackageNotFoundError:
        return []  # installed_problems names it


def _lock() -> tuple[Lock, list[str], list[str]]:
    return parse_lock(LOCK.read_text())


def _roots() -> list[Requirement]:
    return pyproject_requirements(tomllib.loads(PYPROJECT.read_text()))


# ---------------------------------------------------------------------------------------------------
# the tests


def test_lock_locks_each_package_once_with_a_sha256():
    packages, _, problems = _lock()
    assert len(packages) > 100, f"{LOCK.name}: only {len(packages)} packages"
    assert not problems, f"{LOCK.name}:\n" + "\n".join(problems)


def test_lock_admits_every_requirement_of_pyproject():
    problems = pyproject_problems(_lock()[0], _roots())
    assert not problems, f"{LOCK.name} against pyproject.toml:\n" + "\n".join(problems)


def test_lock_is_the_closure_of_pyproject():
    packages = _lock()[0]
    problems = installed_problems(packages, _installed_version)  # the Requires-Dist below are the installed ones
    problems += closure_problems(packages, _roots(), _installed_requires)
    assert not problems, f"{LOCK.name}, its closure read from the installed packages:\n" + "\n".join(problems)


def test_torch_is_the_cpu_build_from_pytorch_index():
    packages, options, _ = _lock()
    assert Version(packages["torch"][0]).local == "cpu", f"torch: locked {packages['torch'][0]}, not a +cpu build"
    assert f"--extra-index-url {TORCH_CPU_INDEX}" in options, f"{LOCK.name}: no --extra-index-url {TORCH_CPU_INDEX}"


def test_the_checkers_catch_broken_input():
    h = "0" * 64
    text = f"--extra-index-url x\n# c\na==1.0 \\\n    --hash=sha256:{h}\nB_c==2.0\na==1.1 --hash=sha256:{h}\nd>=1\n"
    packages, options, problems = parse_lock(text)
    assert options == ["--extra-index-url x"] and set(packages) == {"a", "b-c"}
    assert problems == ["b-c==2.0: no sha256 hash (`--hash=sha256:<64 hex digits>`)", "a: locked twice (1.0 and 1.1)",
                        "d>=1: not name==version"]

    packages = {"a": ("1.0", [h]), "b": ("2.0", [h]), "c": ("1.0", [h]), "stale": ("1.0", [h])}
    metadata = {"a": ["b>=2", 'c<1; extra == "x"', 'gone; python_version < "3"'], "b": ['d; extra == "x"'], "c": []}
    roots = [Requirement("a[x]==1.0"), Requirement("e"), Requirement("b<2")]
    assert pyproject_problems(packages, roots) == [
        "e: pyproject.toml requires e, not locked (make lock)",
        "b: locked 2.0, pyproject.toml requires b<2 (make lock)"]
    assert sorted(closure_problems(packages, roots, metadata.__getitem__)) == [
        "b: locked 2.0, pyproject.toml requires b<2 (make lock)",
        "c: locked 1.0, a[x] requires c<1; extra == \"x\" (make lock)",
        "e: pyproject.toml requires e, not locked (make lock)",
        "stale: locked, but nothing of pyproject.toml's closure requires it (make lock)"]
    versions = {"a": "1.0", "b": "2.1", "c": "1.0"}
    assert installed_problems(packages, versions.get) == [
        "b: installed 2.1, locked 2.0 (make install)", "stale: locked 1.0, not installed (make install)"]
