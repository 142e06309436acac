"""An ``IKOptions`` object as the compiled core takes it (``Packed``), built once per
solver and options object (``OptionPacks``)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..model import Chain, EffectorMode
from ..optim import codes as C
from ..optim.minimize import pack_options
from .options import IKOptions
from .result import ResultLayout


class Packed(NamedTuple):
    """One IKOptions object as the core takes it."""

    options: IKOptions
    stream: bool  # packed for stream frames (``track``: ``IKOptions.ftol``'s default)
    fopt: np.ndarray
    iopt: np.ndarray  # iopt[I_SEED] carries this solver's restart generator along
    policy: np.ndarray
    out_size: int  # length of a frame's output block
    layout: ResultLayout


class OptionPacks:
    """Option vectors, policy table and result layout of one solver, per IKOptions
    object (keyed by identity: the options a session reuses frame after frame) and
    kind of call (a solve, or a stream frame: ``IKOptions.minimize_options``)."""

    def __init__(self, chain: Chain, rng: np.random.Generator) -> None:
        self._chain = chain
        self._rng = rng  # the seeds of the restart generators
        # The task's rows with every effector targeted, as the metric counts them
        # (3 for a position effector, 6 otherwise): they choose metric_every's default.
        self._task_rows = sum(3 if e.mode is EffectorMode.POSITION else 6 for e in chain.effectors)
        self._packed: dict[tuple[int, bool], Packed] = {}
        self.last: Packed | None = None

    def get(self, opts: IKOptions, stream: bool = False) -> Packed:
        last = self.last
        if last is not None and last.options is opts and last.stream == stream:
            return last
        hit = self._packed.get((id(opts), stream))
        if hit is None or hit.options is not opts:
            chain = self._chain
            n = chain.n_dof
            mopts = opts.minimize_options(n, self._task_rows, stream=stream)
            seed = int(self._rng.integers(0, 2**31 - 1))
            fopt, iopt = pack_options(mopts, seed=seed)
            if len(self._packed) > 32:
                self._packed.clear()
            m = len(chain.effectors)
            layout = ResultLayout(
                chain.dof_names,
                chain.effector_names,
                (opts.position_tolerance_m, opts.rotation_tolerance_rad),
                n,
                m,
                chain.followers,
            )
            out_size = 3 * m + n * n + mopts.max_passes * C.N_LOG
            hit = Packed(opts, stream, fopt, iopt, opts.policy.as_array(), out_size, layout)
            self._packed[(id(opts), stream)] = hit
        self.last = hit
        return hit
