"""A validated kinematic model: links joined by joints into a tree, with effectors.

``build_chain`` checks the joints and effectors (``joints``) once and compiles them
into flat arrays (``CompiledChain``, layout in ``layout``) that the numba kinematics
walk. Frames are composed as
``link = parent_link * origin * Tr(pivot) * motion(q) * Tr(-pivot)``; a rotational
joint with axes "xz" has motion Rx(q0) Rz(q1) (intrinsic, in the declared order).

To add a joint kind: a ``JointKind`` member (``joints``), its checks in
``_check_joint``, and its nodes in ``_compile`` (each node is fixed, a rotation or a
translation about a unit axis: ``layout.NODE_*``); a motion that is none of these
needs a new node kind in ``forward.forward_kinematics`` and in the Jacobian columns
of ``solver.ik.kinematics``.

Mimic joints (``Joint.mimic``): a follower's node reads its leader's variable at the
rate ``multiplier`` (``layout.ND_RATE``), its offset folded into the node's fixed
transform, so FK and the exact gradient need nothing else: the follower's column
adds to the leader's. Its limits, mapped back through the affine map, narrow the
leader's range. ``Chain.followers`` gives the followers' values for a q.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..arrays import Matrix, Vector
from ..errors import InvalidModel, InvalidProblem
from .joints import AXIS_VECTORS, Effector, EffectorMode, Joint, JointKind, Mimic, finite_array
from .layout import (
    ED_AIM,
    ED_TIP,
    ED_WIDTH,
    ED_WP,
    ED_WR,
    EI_MODE,
    EI_NODE,
    MODE_AIM,
    MODE_POSE,
    MODE_POSITION,
    ND_AXIS,
    ND_JAXIS,
    ND_PRE,
    ND_RATE,
    ND_WIDTH,
    NODE_FIXED,
    NODE_ROTATION,
    NODE_TRANSLATION,
)
from .mimic import Followers, check_mimic, narrow_leaders, resolve_mimics
from .notes import ModelNote

# Joints above this many degrees of freedom make a chain's dense BFGS matrix
# (n x n) and its Jacobian walks too slow for a frame budget; the service caps lower.
MAX_DOF_HARD = 2000


@dataclass(frozen=True, slots=True)
class Chain:
    """A validated hierarchy; build with ``build_chain``.

    Attributes:
        joints: In topological order (parents before children).
        effectors: In declaration order.
        root: The base link (the single link with no parent joint).
        dof_names: One name per variable, in the order of q.
        lower, upper: Limits per variable, shape (n_dof,).
        compiled: The flat arrays the compiled kinematics use.
        followers: The mimic joints, which have no variable of their own.
        notes: What an importer read in a way the user should know about (URDF
            conventions such as ``lower > upper`` for an unlimited joint).
    """

    joints: tuple[Joint, ...]
    effectors: tuple[Effector, ...]
    root: str
    dof_names: tuple[str, ...]
    lower: Vector
    upper: Vector
    compiled: CompiledChain
    followers: Followers = field(default_factory=Followers)
    notes: tuple[ModelNote, ...] = ()

    @property
    def n_dof(self) -> int:
        return len(self.dof_names)

    @property
    def effector_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effectors)

    @property
    def link_names(self) -> tuple[str, ...]:
        return (self.root, *(j.child for j in self.joints))

    def mid_limits(self) -> Vector:
        """Middle of each variable's range (0 where a side is infinite)."""
        finite = np.isfinite(self.lower) & np.isfinite(self.upper)
        # -inf + inf would warn (and be NaN): only add where both sides are finite.
        return np.where(
            finite,
            0.5 * (np.where(finite, self.lower, 0.0) + np.where(finite, self.upper, 0.0)),
            0.0,
        )

    def effector_index(self, name: str) -> int:
        for i, e in enumerate(self.effectors):
            if e.name == name:
                return i
        raise InvalidProblem(
            f"unknown effector {name!r}; this chain has {list(self.effector_names)}"
        )


@dataclass(frozen=True, slots=True)
class CompiledChain:
    """Flat arrays for the numba kinematics (layout in ``layout``).

    A joint becomes: a node carrying origin * Tr(pivot) and its first motion, one node
    per further axis, and a node carrying Tr(-pivot) when the pivot is non-zero.
    ``ed`` holds the static part of each effector row (tip frame, aim axis, weights).
    """

    ni: np.ndarray  # int64[n_nodes, 3]
    nd: np.ndarray  # float64[n_nodes, 27]
    ei: np.ndarray  # int64[n_eff, 3]
    ed: np.ndarray  # float64[n_eff, 36]
    link_node: dict[str, int]  # link name -> node whose frame is the link frame (-1 root)
    eff_dofs: tuple[np.ndarray, ...]  # per effector, the variables of its chain (terminator-aware)

    @property
    def n_nodes(self) -> int:
        return int(self.ni.shape[0])


MODE_CODES = {
    EffectorMode.POSITION: MODE_POSITION,
    EffectorMode.POSE: MODE_POSE,
    EffectorMode.AIM: MODE_AIM,
}


def _check_unit_axis(axis: Vector, joint: str, field: str) -> Vector:
    a = finite_array(axis, "axis", joint=joint, field=field)
    if a.shape != (3,):
        raise InvalidModel(f"axis must have 3 components, got {a.shape}", joint=joint, field=field)
    norm = float(np.linalg.norm(a))
    if norm < 1e-9:
        raise InvalidModel("axis must not be zero", joint=joint, field=field)
    return a / norm


def _check_joint(j: Joint) -> Joint:
    """Normalise axes and limits of one joint, naming joint and field in every error."""
    if not j.name:
        raise InvalidModel("joint name must not be empty", field="name")
    if j.parent == j.child:
        raise InvalidModel("a joint cannot connect a link to itself", joint=j.name, field="child")
    pivot = finite_array(j.pivot, "pivot", joint=j.name, field="pivot")
    if pivot.shape != (3,):
        raise InvalidModel("pivot must have 3 components", joint=j.name, field="pivot")
    axis = j.axis
    n = 0
    if j.kind is JointKind.ROTATIONAL:
        axes = j.axes.lower()
        if (
            not 1 <= len(axes) <= 3
            or any(a not in AXIS_VECTORS for a in axes)
            or len(set(axes)) != len(axes)
        ):
            raise InvalidModel(
                f"axes must be 1-3 distinct letters of 'xyz', got {j.axes!r}",
                joint=j.name,
                field="axes",
            )
        n = len(axes)
    elif j.kind is not JointKind.FIXED:
        axis = _check_unit_axis(j.axis, j.name, "axis")
        n = 1
        axes = ""
    else:
        axes = ""
    lower, upper = tuple(float(v) for v in j.lower), tuple(float(v) for v in j.upper)
    if j.kind is JointKind.CONTINUOUS and not lower and not upper:
        lower, upper = (-math.inf,), (math.inf,)
    if len(lower) != n or len(upper) != n:
        raise InvalidModel(
            f"expected {n} lower and upper limits, got {len(lower)} and {len(upper)}",
            joint=j.name,
            field="lower" if len(lower) != n else "upper",
        )
    for k in range(n):
        lo, hi = lower[k], upper[k]
        if math.isnan(lo) or math.isnan(hi):
            raise InvalidModel("limits must not be NaN", joint=j.name, field="lower")
        # A slider may be unlimited (URDF files by Bullet's lower > upper convention).
        unlimited_ok = j.kind in (JointKind.CONTINUOUS, JointKind.PRISMATIC)
        if not unlimited_ok and not (math.isfinite(lo) and math.isfinite(hi)):
            raise InvalidModel(
                "limits must be finite (use a continuous joint for unlimited rotation)",
                joint=j.name,
                field="lower" if not math.isfinite(lo) else "upper",
            )
        if lo > hi:
            raise InvalidModel(f"lower > upper ({lo!r} > {hi!r})", joint=j.name, field="lower")
    if j.mimic is not None:
        check_mimic(j)
    return replace(j, pivot=pivot, axis=axis, axes=axes, lower=lower, upper=upper)


def _check_effector(e: Effector, links: set[str]) -> Effector:
    if not e.name:
        raise InvalidModel("effector name must not be empty", field="name")
    if e.link not in links:
        raise InvalidModel(f"unknown link {e.link!r}", joint=e.name, field="link")
    tip = finite_array(e.tip_offset, "tip_offset", joint=e.name, field="tip_offset")
    if tip.shape != (3,):
        raise InvalidModel("tip_offset must have 3 components", joint=e.name, field="tip_offset")
    rot = finite_array(e.tip_rotation, "tip_rotation", joint=e.name, field="tip_rotation")
    if (
        rot.shape != (3, 3)
        or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6)
        or np.linalg.det(rot) < 0
    ):
        raise InvalidModel(
            "tip_rotation must be a rotation matrix", joint=e.name, field="tip_rotation"
        )
    aim = _check_unit_axis(e.aim_axis, e.name, "aim_axis")
    for name in ("position_weight", "rotation_weight"):
        w = float(getattr(e, name))
        if not (math.isfinite(w) and w >= 0.0):
            raise InvalidModel(f"{name} must be finite and >= 0", joint=e.name, field=name)
    if e.mode is EffectorMode.POSITION and e.position_weight == 0.0:
        raise InvalidModel(
            "a position effector needs position_weight > 0", joint=e.name, field="position_weight"
        )
    if (
        e.mode is not EffectorMode.POSITION
        and e.position_weight == 0.0
        and e.rotation_weight == 0.0
    ):
        raise InvalidModel("all weights are zero", joint=e.name, field="rotation_weight")
    return Effector(
        name=e.name,
        link=e.link,
        tip_offset=tip,
        tip_rotation=rot,
        mode=e.mode,
        aim_axis=aim,
        position_weight=float(e.position_weight),
        rotation_weight=float(e.rotation_weight),
    )


def build_chain(
    joints: Sequence[Joint], effectors: Sequence[Effector], *, max_dof: int = MAX_DOF_HARD
) -> Chain:
    """Validate a hierarchy and compile it.

    Raises:
        InvalidModel: duplicate names, unknown parent, a cycle, several roots, a link
            with two parents, bad axes or limits, non-finite numbers, too many DOF,
            no effector. The error names the joint (or effector) and the field.
    """
    checked = [_check_joint(j) for j in joints]
    seen: set[str] = set()
    for j in checked:
        if j.name in seen:
            raise InvalidModel("duplicate joint name", joint=j.name, field="name")
        seen.add(j.name)
    mimics = resolve_mimics(checked)
    by_child: dict[str, Joint] = {}
    for j in checked:
        if j.child in by_child:
            raise InvalidModel(
                f"link {j.child!r} already has parent joint {by_child[j.child].name!r}",
                joint=j.name,
                field="child",
            )
        by_child[j.child] = j
    parents = {j.parent for j in checked}
    roots = sorted(p for p in parents if p not in by_child)
    # Cycle check: walking up from any link must end at a root.
    for j in checked:
        link, steps = j.child, 0
        while link in by_child:
            link = by_child[link].parent
            steps += 1
            if steps > len(checked):
                raise InvalidModel("the hierarchy contains a cycle", joint=j.name, field="parent")
    if not checked:
        raise InvalidModel("a chain needs at least one joint", field="joints")
    if len(roots) != 1:
        raise InvalidModel(
            f"the hierarchy must have exactly one root link, found {roots}", field="parent"
        )
    root = roots[0]
    # Topological order: breadth-first from the root, children in declaration order.
    children: dict[str, list[Joint]] = {}
    for j in checked:
        children.setdefault(j.parent, []).append(j)
    ordered: list[Joint] = []
    frontier = [root]
    while frontier:
        nxt: list[str] = []
        for link in frontier:
            for j in children.get(link, []):
                ordered.append(j)
                nxt.append(j.child)
        frontier = nxt
    dof_names = tuple(name for j in ordered for name in j.dof_names)
    if len(dof_names) > max_dof:
        raise InvalidModel(
            f"too many degrees of freedom: {len(dof_names)} > {max_dof}", field="joints"
        )
    if len(set(dof_names)) != len(dof_names):
        dup = next(n for n in dof_names if dof_names.count(n) > 1)
        raise InvalidModel("duplicate variable name", joint=dup, field="name")
    if not effectors:
        raise InvalidModel("a chain needs at least one effector", field="effectors")
    links = {root, *(j.child for j in ordered)}
    effs = [_check_effector(e, links) for e in effectors]
    if len({e.name for e in effs}) != len(effs):
        raise InvalidModel("duplicate effector name", field="effectors")
    leaders = [j for j in ordered if j.mimic is None]
    lower = np.array([v for j in leaders for v in j.lower], dtype=np.float64)
    upper = np.array([v for j in leaders for v in j.upper], dtype=np.float64)
    var: dict[str, int] = {}  # joint -> its first variable, in the order of q
    n_vars = 0
    for j in leaders:
        var[j.name] = n_vars
        n_vars += len(j.dof_names)
    notes = narrow_leaders(ordered, mimics, lower, upper, var)
    compiled = _compile(ordered, effs, root, var, mimics)
    followers = [j.name for j in ordered if j.name in mimics]
    return Chain(
        tuple(ordered),
        tuple(effs),
        root,
        dof_names,
        lower,
        upper,
        compiled,
        Followers(
            tuple(followers),
            np.array([var[mimics[n].joint] for n in followers], dtype=np.int64),
            np.array([mimics[n].multiplier for n in followers], dtype=np.float64),
            np.array([mimics[n].offset for n in followers], dtype=np.float64),
        ),
        tuple(notes),
    )


def _translation_only(t: Vector) -> Matrix:
    m = np.zeros((3, 4))
    m[:, :3] = np.eye(3)
    m[:, 3] = t
    return m


def _compose(a: Matrix, b: Matrix) -> Matrix:
    out = np.empty((3, 4))
    out[:, :3] = a[:, :3] @ b[:, :3]
    out[:, 3] = a[:, :3] @ b[:, 3] + a[:, 3]
    return out


def _motion(j: Joint, value: float) -> Matrix:
    """A single-axis joint's motion for one value, as a 3x4 transform."""
    if j.kind is JointKind.PRISMATIC:
        return _translation_only(value * j.axis)
    ux, uy, uz = j.axis
    k = np.array([[0.0, -uz, uy], [uz, 0.0, -ux], [-uy, ux, 0.0]])
    m = np.zeros((3, 4))
    m[:, :3] = np.eye(3) + math.sin(value) * k + (1.0 - math.cos(value)) * (k @ k)
    return m


def _compile(
    ordered: list[Joint],
    effectors: list[Effector],
    root: str,
    var: dict[str, int],
    mimics: dict[str, Mimic],
) -> CompiledChain:
    parent: list[int] = []
    pre: list[Matrix] = []
    kind: list[int] = []
    axis: list[Vector] = []
    dof: list[int] = []
    rate: list[float] = []
    link_node: dict[str, int] = {root: -1}
    node_joint: list[str] = []

    def add(p: int, m: Matrix, k: int, a: Vector, d: int, owner: str, r: float = 1.0) -> int:
        parent.append(p)
        pre.append(m)
        kind.append(k)
        axis.append(a)
        dof.append(d)
        rate.append(r)
        node_joint.append(owner)
        return len(parent) - 1

    for j in ordered:
        p = link_node[j.parent]
        has_pivot = bool(np.any(j.pivot != 0.0))
        base = (
            _compose(j.origin.as_matrix34(), _translation_only(j.pivot))
            if has_pivot
            else j.origin.as_matrix34()
        )
        mimic = mimics.get(j.name)
        if j.kind is JointKind.FIXED:
            p = add(p, base, NODE_FIXED, np.zeros(3), -1, j.name)
        elif j.kind is JointKind.ROTATIONAL:
            m = base
            for i, a in enumerate(j.axes):
                p = add(p, m, NODE_ROTATION, np.array(AXIS_VECTORS[a]), var[j.name] + i, j.name)
                m = _translation_only(np.zeros(3))
        elif mimic is not None and mimic.multiplier == 0.0:
            # Held at its offset whatever the leader does: a fixed node.
            held = _compose(base, _motion(j, mimic.offset))
            p = add(p, held, NODE_FIXED, np.zeros(3), -1, j.name)
        else:
            k = NODE_TRANSLATION if j.kind is JointKind.PRISMATIC else NODE_ROTATION
            if mimic is None:
                p = add(p, base, k, j.axis, var[j.name], j.name)
            else:
                # multiplier x leader + offset: the offset's motion is fixed (rotations
                # about one axis commute, as do translations along one).
                moved = _compose(base, _motion(j, mimic.offset))
                p = add(p, moved, k, j.axis, var[mimic.joint], j.name, mimic.multiplier)
        if has_pivot and j.kind is not JointKind.FIXED:
            p = add(p, _translation_only(-j.pivot), NODE_FIXED, np.zeros(3), -1, j.name)
        elif has_pivot:
            # A fixed joint has no motion: fold -pivot into the same node.
            pre[p] = _compose(pre[p], _translation_only(-j.pivot))
        link_node[j.child] = p

    node_parent = np.array(parent, dtype=np.int64)
    node_dof = np.array(dof, dtype=np.int64)
    terminators = {j.name for j in ordered if j.terminator}
    eff_dofs: list[np.ndarray] = []
    for e in effectors:
        # Variables of this effector's chain: walk up until (and including) a terminator.
        dofs: list[int] = []
        node = link_node[e.link]
        while node >= 0:
            if node_dof[node] >= 0:
                dofs.append(int(node_dof[node]))
            owner = node_joint[node]
            parent_node = node_parent[node]
            if owner in terminators and (parent_node < 0 or node_joint[parent_node] != owner):
                break
            node = parent_node
        # A follower reads its leader's variable: count it once.
        eff_dofs.append(np.array(sorted(set(dofs)), dtype=np.int64))
    n_nodes = len(parent)
    ni = np.zeros((n_nodes, 3), dtype=np.int64)
    nd = np.zeros((n_nodes, ND_WIDTH))
    for k in range(n_nodes):
        ni[k] = (parent[k], kind[k], dof[k])
        nd[k, ND_PRE : ND_PRE + 12] = pre[k].reshape(-1)
        nd[k, ND_AXIS : ND_AXIS + 3] = axis[k]
        nd[k, ND_JAXIS : ND_JAXIS + 3] = rate[k] * np.asarray(axis[k])
        nd[k, ND_RATE] = rate[k]
    ei = np.zeros((len(effectors), 3), dtype=np.int64)
    ed = np.zeros((len(effectors), ED_WIDTH))
    for i, e in enumerate(effectors):
        ei[i, EI_NODE] = link_node[e.link]
        ei[i, EI_MODE] = MODE_CODES[e.mode]
        tip = np.empty((3, 4))
        tip[:, :3] = e.tip_rotation
        tip[:, 3] = e.tip_offset
        ed[i, ED_TIP : ED_TIP + 12] = tip.reshape(-1)
        ed[i, ED_AIM : ED_AIM + 3] = e.aim_axis
        ed[i, ED_WP] = e.position_weight
        ed[i, ED_WR] = e.rotation_weight
    return CompiledChain(ni=ni, nd=nd, ei=ei, ed=ed, link_node=link_node, eff_dofs=tuple(eff_dofs))
