"""The service's cost of bone output per frame: rendering and encoding an answer with
and without ``bones``, for CesiumMan (shared/assets) with both hands and both feet as
effectors, in Unity's conventions (so the conversion runs), over a solved stream.

Measured per frame (median and 99th percentile, microseconds) and per answer (bytes,
JSON): the plain FrameResult; with ``local_rotations`` (19 bones); with that and the
world transforms of the four effector bones. What ``service/convert`` does on the event
loop after each solve; the solve itself is not counted (bench/skeleton.py has it).

    OPENBLAS_NUM_THREADS=1 python -m bench.bone_output --frames 300
"""

from __future__ import annotations

import argparse
import base64
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import orjson  # noqa: E402

import schemas as S  # noqa: E402
from bench.skeleton import assets_dir, smooth_poses  # noqa: E402
from service import convert  # noqa: E402
from service.config import Settings  # noqa: E402
from service.solving import make_solver  # noqa: E402
from solver.ik import pose_targets  # noqa: E402

HANDS_FEET = ("node_18", "node_15", "node_10", "node_6")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--assets", default=None)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    glb = (assets_dir(args.assets) / "CesiumMan.glb").read_bytes()
    spec = S.GltfChain(
        format="gltf",
        glb_base64=base64.b64encode(glb).decode(),
        effectors=[S.BoneEffectorSpec(bone=b) for b in HANDS_FEET],
    )
    settings = Settings()
    view = convert.chain_from_spec(spec, settings, S.Conventions(preset="unity"))
    solver = make_solver(view, convert.session_defaults(settings))
    chain = view.chain
    results = [
        solver.track(pose_targets(chain, q))
        for q in smooth_poses(chain, args.frames, 0.3, args.seed)
    ]
    outputs = {
        "no bones": None,
        "local_rotations": S.BoneOutput(local_rotations=True),
        "local_rotations + 4 world": S.BoneOutput(local_rotations=True, world=list(HANDS_FEET)),
    }
    print(
        f"CesiumMan, {len(view.skeleton.moving) if view.skeleton else 0} moving bones, "
        f"{chain.n_dof} variables, {sum(r.success for r in results)}/{args.frames} solved"
    )
    for label, output in outputs.items():
        if output is not None:  # the first call loads the compiled FK: not a frame's cost
            convert.bones_dict(view, results[0].q, output)
        times, sizes = [], []
        for r in results:
            start = time.perf_counter()
            answer = convert.result_dict(r, 1, 0.0)
            if output is not None:
                answer["bones"] = convert.bones_dict(view, r.q, output)
            encoded = orjson.dumps(answer)
            times.append((time.perf_counter() - start) * 1e6)
            sizes.append(len(encoded))
        print(
            f"{label}: render + encode p50 {np.median(times):.0f} us, "
            f"p99 {np.percentile(times, 99):.0f} us; {int(np.median(sizes))} bytes"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
