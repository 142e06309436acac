"""service/demo_assets/demo.js and demo-worker.js are what clients/demo builds: rebuilt
here, byte for byte.

The page's bundles are committed (so that a fresh clone serves /demo with no npm and no
network); this test keeps it honest: `npm ci` with the lock file's pinned versions,
`tsc --noEmit` over the page's TypeScript (and the client's, which it imports), then
esbuild into a temporary folder, and the bytes must equal the committed bundles and the
licence file. After changing clients/demo/src or clients/typescript/src, rebuild with
`cd clients/demo && npm ci && npm run build` and commit service/demo_assets/.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from .test_typescript_client import npm_or_skip, run

pytestmark = [pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "clients" / "demo"
ASSETS = ROOT / "service" / "demo_assets"


def test_the_committed_bundle_is_what_the_sources_build(tmp_path: Path) -> None:
    npm = npm_or_skip()
    run([npm, "ci", "--no-audit", "--no-fund"], cwd=DEMO)
    run([npm, "run", "check"], cwd=DEMO)
    run(["node", "build.mjs", str(tmp_path)], cwd=DEMO)
    names = {p.name for p in tmp_path.iterdir()}
    assert names == {"demo.js", "demo-worker.js", "demo.js.LEGAL.txt"}, names
    for name in sorted(names):
        built, committed = (tmp_path / name).read_bytes(), (ASSETS / name).read_bytes()
        assert built == committed, f"{name} differs from a fresh build: rebuild it (see above)"
