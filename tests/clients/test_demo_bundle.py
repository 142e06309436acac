"""service/demo_assets/demo.js is what clients/demo builds: rebuilt here, byte for byte.

The page's bundle is committed (so that a fresh clone serves /demo with no npm and no
network); this test keeps it honest: `npm ci` with the lock file's pinned versions,
`tsc --noEmit` over the page's TypeScript (and the client's, which it imports), then
esbuild into a temporary folder, and the bytes must equal the committed bundle and its
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
    out = tmp_path / "demo.js"
    run(["node", "build.mjs", str(out)], cwd=DEMO)
    for name in ("demo.js", "demo.js.LEGAL.txt"):
        built, committed = (tmp_path / name).read_bytes(), (ASSETS / name).read_bytes()
        assert built == committed, f"{name} differs from a fresh build: rebuild it (see above)"
