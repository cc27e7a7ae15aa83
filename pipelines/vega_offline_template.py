"""Build ``pipelines/vega/offline.html``: DVC's plots page with vega, vega-lite and vega-embed inlined.

``dvc plots show`` writes a page whose ``{scripts}`` placeholder DVC fills with ``<script src=...>`` tags for
cdn.jsdelivr.net, so the page is blank without internet (most cluster nodes). This repository's
``.dvc/config`` names ``pipelines/vega/offline.html`` as the ``plots.html_template`` instead: the same page
as dvc-render's default, the three libraries inlined and the ``{scripts}`` placeholder left out, so the
written page needs no network and still renders wherever ``-o`` puts it or the page is copied.

The libraries are the builds DVC 3.67 (dvc-render 1.0.2) loads from the CDN, at its versions
(``PINS``; tests/test_dvc_plots_offline.py checks they still match dvc-render's), taken from the npm
registry: ``npm pack`` tarballs, checked against the registry's sha512 integrity, their
``build/<name>.min.js`` (the file the CDN serves for ``<name>@<version>``) inlined, its trailing
``sourceMappingURL`` comment dropped, and a banner naming the package, version, licence, the tarball's
integrity and the sha256 of the inlined text. Their licences go to ``pipelines/vega/LICENSE.<name>``.

Rebuild (needs npm and the registry, e.g. after a DVC upgrade changed the versions)::

    .venv/bin/python -m pipelines.vega_offline_template               # npm pack into a temporary directory
    .venv/bin/python -m pipelines.vega_offline_template --tarballs D  # D holds vega-5.20.2.tgz etc. already
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import json
import re
import subprocess
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT_DIR = ROOT / "pipelines" / "vega"
TEMPLATE = OUT_DIR / "offline.html"

PINS = {
    "vega": ("5.20.2",
             "sha512-qmH7aD9GGPpssVdxL1xgcdxTbQzyRUeRR16Os385ymvQhiwCYQNA6+eXUPAZDTVLfk0RXu6Jzj6kUE5jQ80EVw=="),
    "vega-lite": ("5.2.0",
                  "sha512-Yxcg8MvYfxHcG6BbkaKT0oVCIMIcE19UvqIsEwBmyd/7h2nzW7oRnID81T8UrY7hpDrIr6wa2JADOT2dhGNErw=="),
    "vega-embed": ("6.18.2",
                   "sha512-wcDyQPE4J5aiCDc3/suH5RQDvrKkjuLkhzUcbOLwEkNF8/+pp17tS0JghzEvAPNRg+5aG1/N2ydixq8Lk3dOlg=="),
}
"""package -> (version, npm dist.integrity of its tarball), in load order (vega-embed needs the other two)."""

BANNER = re.compile(r"/\*! (?P<name>[\w-]+)@(?P<version>[\d.]+) (?P<file>\S+) \((?P<license>[^)]+)\), npm "
                    r"(?P<integrity>sha512-\S+), sha256 of the rest of this script: (?P<sha256>[0-9a-f]{64}) \*/\n")
"""The banner opening each inlined script."""

PAGE = """<!DOCTYPE html>
<html>
<head>
    <meta charset="utf-8">
    {refresh_tag}
    <title>DVC Plot</title>
    <!-- This repository's dvc plots template (pipelines/vega_offline_template.py builds it): vega, vega-lite and
         vega-embed inlined from the npm registry at the versions DVC loads from its CDN, so the page renders
         with no network. -->
SCRIPTS
    <style>
        table {
            border-spacing: 15px;
        }
    </style>
</head>
<body>
    {plot_divs}
</body>
</html>
"""
"""dvc-render 1.0.2's ``PAGE_HTML`` with the libraries in place of the CDN's ``{scripts}``; ``{refresh_tag}``
and ``{plot_divs}`` are DVC's placeholders."""

SOURCE_MAP = re.compile(r"\n?//# sourceMappingURL=\S+\s*$")


def _check_integrity(tarball: Path, integrity: str) -> None:
    digest = "sha512-" + base64.b64encode(hashlib.sha512(tarball.read_bytes()).digest()).decode()
    if digest != integrity:
        raise SystemExit(f"{tarball}: integrity {digest}, expected {integrity} (the registry's)")


def _npm_pack(directory: Path) -> None:
    specs = [f"{name}@{version}" for name, (version, _) in PINS.items()]
    subprocess.run(["npm", "pack", "--silent", *specs], cwd=directory, check=True, stdout=subprocess.DEVNULL)


def build(tarballs: Path) -> str:
    """The template's text from the tarballs in ``tarballs``; writes the licences to ``OUT_DIR``."""
    scripts = []
    for name, (version, integrity) in PINS.items():
        tarball = tarballs / f"{name}-{version}.tgz"
        _check_integrity(tarball, integrity)
        with tarfile.open(tarball) as archive:
            build_file = f"build/{name}.min.js"
            code = archive.extractfile(f"package/{build_file}").read().decode("utf-8")
            licence = archive.extractfile("package/LICENSE").read().decode("utf-8")
            package = json.loads(archive.extractfile("package/package.json").read())
        if package["version"] != version or package.get("jsdelivr") != build_file:
            raise SystemExit(f"{tarball}: version {package['version']}, CDN file {package.get('jsdelivr')}")
        code = SOURCE_MAP.sub("", code).rstrip("\n") + "\n"
        if "</script" in code.lower() or any(f"{{{p}}}" in code for p in ("scripts", "plot_divs", "refresh_tag")):
            raise SystemExit(f"{name}: its code cannot be inlined as is (a </script or a DVC placeholder)")
        sha256 = hashlib.sha256(code.encode("utf-8")).hexdigest()
        banner = (f"/*! {name}@{version} {build_file} ({package['license']}), npm {integrity}, "
                  f"sha256 of the rest of this script: {sha256} */\n")
        assert BANNER.fullmatch(banner), banner
        scripts.append(f"    <script>{banner}{code}</script>")
        (OUT_DIR / f"LICENSE.{name}").write_text(licence)
    return PAGE.replace("SCRIPTS", "\n".join(scripts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tarballs", type=Path, help="directory holding the npm pack tarballs (default: npm pack)")
    args = parser.parse_args()
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tarballs = args.tarballs
        if tarballs is None:
            tarballs = Path(tmp)
            _npm_pack(tarballs)
        TEMPLATE.write_text(build(tarballs), encoding="utf-8")
    print(f"{TEMPLATE.relative_to(ROOT)}: {TEMPLATE.stat().st_size} bytes")


if __name__ == "__main__":
    main()
