"""Clustered explicit FEM (eqs. 4-5): symplectic Euler driven by the fused cluster force kernel.

All sub-steps of one step run inside one numba call: fixed vertices held at rest, force, constraint forces,
velocity and position updates, with no Python in between. ``warp=True`` swaps in a warped force on
the same step: per-element corotation by default (fem/materials/element_warping.py: the gradient of an energy, so it
cannot feed energy in), stable Neo-Hookean elements (fem/materials/neohookean.py: an energy smooth through inversion,
``warping_model="neohookean"``), or the paper's per-vertex warping (``warping_model="vertex"``,
fem/materials/warping.py: eq. 10, symmetrised) for comparison, which has no energy and is refused unless
``allow_unbounded_warping``; the linear path is a separate compiled function.
The critical step is the linear K's. A corotated element stretched several times its size is stiffer than
that (its tangent's twist modes grow with lambda tr(S - I)), so a warped step is planned for the linear K's
largest eigenvalue times a stretch factor (``StretchPlan``): undamped, the bar with a vertex torn 0.5 m
away stays bounded at the default safety (tests/test_hard_cases.py); the few per cent its energy still
gains come from the elements the tear inverts (benchmarks/stability_table.py's docstring).

Python per step is kept to what can change: the sub-step plan is cached while h and the attachment gains'
maxima are unchanged, prescribed vertices cost nothing when there are none, and divergence is still
checked every step (the kernel returns whether every |u| stayed under the limit, which a nan fails).

What a build injects: the step sources call compiled functions by global names that no import defines, bound
per build by numba_config.compiled (``_builds``), hence ``# noqa: F821`` at each call: ``stiffness`` (the
serial or threaded linear sweep) in ``_symplectic_euler``, ``warped_e`` and ``later_e`` (the model's pass,
serial or threaded, for the first sub-step and for the later ones) in ``_warped_symplectic_euler``, and ``step``
(the matching attached step, called with no attachments) in the two ``_free_`` sources.
"""
from __future__ import annotations

import time

import numba
import numpy as np

from ..kernels.cluster_force_kernel import kernel_input_serial, stiffness_slices_parallel, stiffness_slices_serial
from ..model import Control, FemModel, State
from ...numba_config import AUTO_THREADS_MIN_VERTICES, SERIAL, compiled
from ..stability import check_safety, control_critical_step, max_eigenvalue, plan_substeps
from ..materials.material_model import ClusteredParts, MaterialModel
from ..materials.registry import material_model
from ..materials.stretch import StretchPlan
from .base import StepCommon, StepInfo


def _update(n, h, zeta, inv_mass3, kw, xi, mass3, f_const, rest, u, v, w, warped, limit, refresh):
    """f = -kw - xi M v; v += h M^-1 (f + f_const), u += h v; if ``refresh``, w <- the next sub-step's force
    input (the last sub-step skips it: the next step's _prepare computes w anyway). Returns True while every
    |u| <= limit.

    The sweep leaves K w (linear) or e (warped, its counterpart: fem/kernels/warped_force_kernel.py) minus the
    attachment forces in ``kw`` (rows in vertex order) and the mass damping to this loop. ``inv_mass3`` and
    ``mass3`` are per coordinate (3n), inv_mass3 0 at held vertices, so the loop runs over flat arrays and
    vectorizes. A non-finite v reaches u in the same loop (u += h v, also at held vertices: 0 * inf is nan),
    and a nan fails the comparison, so one flag covers divergence and non-finite values; it is an integer
    chain, where the float max and nan-probe sum it replaced were serial float chains.
    """
    uf, vf, ff, cf = u.reshape(-1), v.reshape(-1), kw.reshape(-1), f_const.reshape(-1)
    ok = True
    for k in range(3 * n):
        f = -ff[k] - (xi * mass3[k]) * vf[k]
        vc = vf[k] + h * inv_mass3[k] * (f + cf[k])
        uc = uf[k] + h * vc
        vf[k] = vc
        uf[k] = uc
        ok &= abs(uc) <= limit
    if refresh:
        kernel_input_serial(n, zeta, rest, u, v, w, warped)
    return ok


def _prepare(n, zeta, fixed, rest, u, v, w, warped):
    """Fixed vertices held at rest (the state may come from outside); w <- the first force's input."""
    for a in range(fixed.shape[0]):
        i = fixed[a]
        for c in range(3):
            u[i, c] = 0.0
            v[i, c] = 0.0
    kernel_input_serial(n, zeta, rest, u, v, w, warped)


def _attach(tau, mass, att_idx, att_u, att_v, att_a, att_kp, att_kd, u, v, kw):
    """kw -= m_i (a* + kp (u* - u) + kd (v* - v)) at the attached vertices, targets advanced by tau (kw holds
    K w or e, which the update subtracts)."""
    for a in range(att_idx.shape[0]):
        i = att_idx[a]
        m = -mass[i]
        for c in range(3):
            tu = att_u[a, c] + tau * att_v[a, c] + 0.5 * tau * tau * att_a[a, c]
            tv = att_v[a, c] + tau * att_a[a, c]
            kw[i, c] += m * (att_a[a, c] + att_kp[a] * (tu - u[i, c]) + att_kd[a] * (tv - v[i, c]))


_update = numba.njit(**SERIAL)(_update)
_prepare = numba.njit(**SERIAL)(_prepare)
_attach = numba.njit(**SERIAL)(_attach)


_NO_INDEX = np.zeros(0, np.int64)
_NO_VEC = np.zeros((0, 3))
_NO_GAIN = np.zeros(0)


# The fused steps, linear and warped, each with its attachment-free variant, one source each. The globals
# ``stiffness``, ``warped_e``, ``later_e`` and ``step`` are bound per build (numba_config.compiled: serial or threaded
# kernels; not closures, which numba's cache cannot keep across processes).

def _symplectic_euler(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner,
                      mass, mass3, inv_mass3, fixed, u, v, f_const, zeta, xi, h, nsub, limit, w, kw,
                      att_idx, att_u, att_v, att_a, att_kp, att_kd):
    """The linear step around one build of the force sweep (``stiffness``).

    ``w`` = u + zeta v is the kernel's input; it is refreshed in the update loop. A sub-step makes the slice
    sweep, which leaves K w in ``kw`` in vertex order, and one flat pass over the vertices, which finishes the
    force (-K w - xi M v, plus the attachments, subtracted from kw) inside the update. Returns False if any |u|
    passed ``limit`` or anything is not finite.
    """
    n = u.shape[0]
    _prepare(n, zeta, fixed, u, u, v, w, False)
    ok = True                               # nsub >= 1 (plan_substeps): the last _update sets it
    for s in range(nsub):
        stiffness(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner, w, kw)  # noqa: F821 (bound)
        _attach(s * h, mass, att_idx, att_u, att_v, att_a, att_kp, att_kd, u, v, kw)
        ok = _update(n, h, zeta, inv_mass3, kw, xi, mass3, f_const, u, u, v, w, False, limit, s + 1 < nsub)
    return ok


def _free_symplectic_euler(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner,
                           mass, mass3, inv_mass3, fixed, u, v, f_const, zeta, xi, h, nsub, limit, w, kw):
    """The linear ``step`` for a body with no attachments: numba's dispatch costs ~75 ns per array argument,
    and six empty arrays were 0.45 us of a 9 us step on the paper's sphere."""
    return step(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner,  # noqa: F821 (bound)
                mass, mass3, inv_mass3, fixed, u, v, f_const, zeta, xi, h, nsub, limit, w, kw,
                _NO_INDEX, _NO_VEC, _NO_VEC, _NO_VEC, _NO_GAIN, _NO_GAIN)


def _warped_symplectic_euler(gradients, slices, rest, work,
                             mass, mass3, inv_mass3, fixed, u, v, f_const, zeta, xi, h, nsub, limit, w, e,
                             first_force, att_idx, att_u, att_v, att_a, att_kp, att_kd):
    """The warped step around one build of the warped kernel (``warped_e``; ``later_e`` for the sub-steps after
    the first, which nothing plans from: the Neo-Hookean pass without its bounds); w = x0 + u + zeta v. The kernel
    leaves e, the warped counterpart of K w (fem/kernels/warped_force_kernel.py), in vertex order, and the update
    finishes the force as in the linear step. ``first_force`` false: the caller has made the first sub-step's
    force (``_warped_first_force``: the Neo-Hookean step plans its sub-steps from the bounds that pass leaves)."""
    n = u.shape[0]
    if first_force:
        _prepare(n, zeta, fixed, rest, u, v, w, True)
    ok = True                               # nsub >= 1 (plan_substeps): the last _update sets it
    for s in range(nsub):
        if s > 0:
            later_e(gradients, slices, u, w, work)  # noqa: F821 (bound)
        elif first_force:
            warped_e(gradients, slices, u, w, work)  # noqa: F821
        _attach(s * h, mass, att_idx, att_u, att_v, att_a, att_kp, att_kd, u, v, e)
        ok = _update(n, h, zeta, inv_mass3, e, xi, mass3, f_const, rest, u, v, w, True, limit, s + 1 < nsub)
    return ok


def _free_warped_symplectic_euler(gradients, slices, rest, work,
                                  mass, mass3, inv_mass3, fixed, u, v, f_const, zeta, xi, h, nsub, limit, w, e,
                                  first_force):
    """The warped ``step`` for a body with no attachments."""
    return step(gradients, slices, rest, work,  # noqa: F821 (bound)
                mass, mass3, inv_mass3, fixed, u, v, f_const, zeta, xi, h, nsub, limit, w, e, first_force,
                _NO_INDEX, _NO_VEC, _NO_VEC, _NO_VEC, _NO_GAIN, _NO_GAIN)


def _warped_first_force(gradients, slices, rest, work, fixed, u, v, zeta, w):
    """Fixed vertices held at rest, w and e: the first sub-step's force of a warped step, which the step then
    takes with ``first_force`` false."""
    _prepare(u.shape[0], zeta, fixed, rest, u, v, w, True)
    warped_e(gradients, slices, u, w, work)  # noqa: F821 (bound)


def _builds(step_source, free_source, suffix, **kernel):
    """(attached, attachment-free) builds of one step source around the given kernel build."""
    step = compiled(step_source, suffix, **kernel)
    return step, compiled(free_source, suffix, step=step)


# (attached, attachment-free) builds of the linear step, serial and threaded sweeps
_step_serial = _builds(_symplectic_euler, _free_symplectic_euler, "", stiffness=stiffness_slices_serial)
_step_parallel = _builds(_symplectic_euler, _free_symplectic_euler, "_parallel", stiffness=stiffness_slices_parallel)
_WARPED_BUILDS: dict[str, tuple] = {}       # a model's build_suffix -> (its kernels, its step builds)


def step_builds(parts: ClusteredParts) -> tuple:
    """((serial attached, serial free), (threaded attached, threaded free), first force (serial, threaded) or
    None) of the step around a model's force pass (the linear sweep when it has none); made once per model
    and kept (they are compiled functions, the same for every body of the model)."""
    if parts.warped_e is None:
        return _step_serial, _step_parallel, None
    key = parts.build_suffix
    kernels = (parts.warped_e, parts.later_e or parts.warped_e)
    if key not in _WARPED_BUILDS:
        (serial, parallel), (later_serial, later_parallel) = kernels
        first = None
        if parts.bound is not None:     # the step makes its first force before it plans from the bounds
            first = (compiled(_warped_first_force, key, warped_e=serial),
                     compiled(_warped_first_force, key + "_parallel", warped_e=parallel))
        steps = (_builds(_warped_symplectic_euler, _free_warped_symplectic_euler, key, warped_e=serial,
                         later_e=later_serial),
                 _builds(_warped_symplectic_euler, _free_warped_symplectic_euler, key + "_parallel",
                         warped_e=parallel, later_e=later_parallel), first)
        _WARPED_BUILDS[key] = (kernels, steps)
    built, steps = _WARPED_BUILDS[key]
    if built != kernels:
        raise ValueError(f"build_suffix {key!r} names another model's step builds: give each material model's "
                         "ClusteredParts a build_suffix of its own")
    return steps


class ThreadChoice:
    """Serial or threaded build of the step, chosen by measured time; both give bit-identical results.

    A probe runs the two builds alternately for PROBE steps each (after one warm-up step of each) and keeps
    the one with the lower median. Threads pay only while both cores are free: on a 2-core machine where
    another process holds a core, the thread pool's join waits for the OS scheduler (the warped jelly man
    went from 0.3 ms to 5-8 ms per step). So SLOW_RUN threaded steps in a row slower than SLOW x the serial
    median (one is not enough: an interrupt can stall any step) end the probe or drop back to serial at
    once, and the probe is repeated after ``interval`` steps, doubling (up to MAX_INTERVAL) each time
    threads lose, so a busy machine costs a couple of slow steps now and then.
    """
    PROBE = 16
    SLOW = 3.0
    SLOW_RUN = 2
    INTERVAL = 4096
    MAX_INTERVAL = 1 << 17

    def __init__(self):
        self.parallel = False           # the build in use outside probes
        self.serial_median = float("inf")
        self.interval = self.INTERVAL
        self._slow = 0
        self._start_probe()

    def _start_probe(self):
        self._k = -2                    # two warm-up steps (first calls, pool start), then 2 PROBE timed ones
        self._times = ([], [])
        self.probing = True

    def _end_probe(self, parallel: bool):
        self.parallel = parallel
        self.probing = False
        self.interval = self.INTERVAL if parallel else min(2 * self.interval, self.MAX_INTERVAL)
        self._k = 0
        self._slow = 0

    def use_parallel(self) -> bool:
        """The build for the next step."""
        return (self._k % 2 != 0) if self.probing else self.parallel

    def _too_slow(self, parallel: bool, seconds: float) -> bool:
        if parallel:
            self._slow = self._slow + 1 if seconds > self.SLOW * self.serial_median else 0
        return self._slow >= self.SLOW_RUN

    def record(self, parallel: bool, seconds: float) -> None:
        """The time the build given took for the step just run."""
        k = self._k
        self._k += 1
        if not self.probing:
            if self._too_slow(parallel, seconds):
                self._end_probe(False)
            elif self._k >= self.interval:
                self._start_probe()
            return
        if k < 0:
            return
        self._times[parallel].append(seconds)
        if not parallel:
            self.serial_median = float(np.median(self._times[False]))
        if self._too_slow(parallel, seconds):
            self._end_probe(False)
        elif k == 2 * self.PROBE - 1:
            self._end_probe(float(np.median(self._times[True])) < self.serial_median)


class ClusteredExplicit:
    """The paper's method. ``safety`` scales the critical step; ``threads`` forces the threaded kernel on/off
    (default: from AUTO_THREADS_MIN_VERTICES vertices, the faster build as measured by ThreadChoice);
    ``warp`` turns on stiffness warping, ``warping_model`` which: 'element' (per-element corotation, the
    gradient of an energy: fem/materials/element_warping.py), 'neohookean' (stable Neo-Hookean elements, no rotation,
    smooth through inversion: fem/materials/neohookean.py) or 'vertex' (the paper's eq. 10, symmetrised:
    fem/materials/warping.py; refused with StabilityError unless ``allow_unbounded_warping``:
    fem/materials/warping_models.py); ``plan_stretch=False`` plans a warped step from the linear K alone (for
    comparison: fem/materials/stretch.py says why it is on)."""
    name = "clustered"

    def __init__(self, model: FemModel, safety: float = 0.8, max_substeps: int = 10000,
                 threads: bool | None = None, lam_max: float | None = None, warp: bool = False,
                 warping_model: str = "element", plan_stretch: bool = True,
                 allow_unbounded_warping: bool = False):
        self.model = model
        self.warp = bool(warp)
        self.material_model: MaterialModel = material_model(self.warp, warping_model)
        self.material_model.check(allow_unbounded_warping, "clustered", model.material)
        self.warping_model = warping_model
        self.safety = check_safety(safety)
        self.max_substeps = max_substeps
        self.lam_max = max_eigenvalue(model) if lam_max is None else lam_max
        n = model.n_vertices
        self.thread_choice = ThreadChoice() if threads is None and n >= AUTO_THREADS_MIN_VERTICES else None
        self.threads = bool(threads)
        self.name = "clustered" + self.material_model.suffix
        parts = self._parts = self.material_model.clustered(model)
        if parts.frames is not None:
            self.frames = parts.frames
        self._model_args, self._w, self._f = parts.model_args, parts.w, parts.e
        serial, parallel, self._first_force = step_builds(parts)
        self._builds = (serial, parallel)
        self._step = self._builds[self.threads]
        self._mass3 = np.repeat(model.mass, 3)
        self._inv_mass3 = np.repeat(np.where(model.fixed, 0.0, 1.0 / model.mass), 3)
        self._common = StepCommon(model)
        m = model.material
        self._zeta, self._xi = float(m.zeta), float(m.xi)
        energy = self.material_model.stretch_energy
        self.stretch = (StretchPlan(model, energy=energy, lam_max=self.lam_max if energy == "neohookean" else None)
                        if energy is not None and plan_stretch else None)
        self._plan_key = None
        self._plan = None
        self._info = None
        self.threaded_steps = 0         # steps run on the threaded build (its worker threads' CPU is not the caller's)

    @property
    def kernels(self) -> tuple:
        """The compiled builds the coming steps run (both threaded and serial while ThreadChoice may pick
        either); the attachment-free builds call these."""
        if self.thread_choice is not None:
            return self._builds[0][0], self._builds[1][0]
        return (self._builds[self.threads][0],)

    def critical_step(self, control: Control | None = None, stiffer: float = 1.0) -> float:
        """h_crit for the linear K's largest eigenvalue times ``stiffer`` (a warped body's stretch factor)."""
        return control_critical_step(self.lam_max * stiffer, self.model.material, control)

    def set_max_substeps(self, n: int) -> None:
        """Refuse a step needing more than ``n`` sub-steps from now on (the cached plan is made again)."""
        self.max_substeps = int(n)
        self._plan_key = None

    def _plan_for(self, h: float, control: Control, stiffer: float = 1.0):
        """The sub-step plan and its StepInfo, recomputed only when h, the attachments' largest gains or the
        stretch factor change."""
        att = control.attachments
        key = (h, stiffer, *att.gain_maxima()) if att.index.size else (h, stiffer)
        if key != self._plan_key:
            self._plan = plan_substeps(h, self.critical_step(control, stiffer), self.safety, self.max_substeps)
            self._info = StepInfo(self._plan.substeps, self._plan.margin)
            self._plan_key = key
        return self._plan

    def _step_args(self, state: State, control: Control, plan, inv_mass3: np.ndarray,
                   first_force: bool = True) -> tuple:
        """The compiled step's arguments up to the attachments (its attachment-free build takes just these);
        ``first_force`` false: the step's first force is made (``_stiffer``)."""
        common = self._common
        args = (*self._model_args, self.model.mass, self._mass3, inv_mass3, common.fixed_index, state.u, state.v,
                common.constant_forces(control), self._zeta, self._xi, plan.h_sub, plan.substeps, common.limit,
                self._w, self._f)
        return (*args, first_force) if self._parts.warped_e is not None else args

    def _stiffer(self, state: State, h: float, parallel: bool) -> tuple[float, bool]:
        """(the stretch factor for a step of h from ``state``, whether the step's first force is made). The
        Neo-Hookean bounds come with the force pass, so its first force is made here, before the plan."""
        stretch = self.stretch
        if stretch is None:
            return 1.0, False
        if self._first_force is None:
            return stretch.factor(state.u, h), False
        self._first_force[parallel](*self._model_args, self._common.fixed_index, state.u, state.v, self._zeta,
                                    self._w)
        # the inverted elements' tighter plan bounds an undamped body's energy; a damped one dissipates the
        # drift, and its quartered sub-step would push real motion past physics.max_substeps
        undamped = self._zeta == 0.0 and self._xi == 0.0
        return stretch.element_factor(self._parts.bound(), h, undamped), True

    def compiled_step(self, state: State, control: Control, h: float) -> tuple:
        """(function, arguments) of one step's compiled part for a body without attachments or prescribed
        vertices, serial build: what ``step`` calls after its Python bookkeeping (benchmarks/core_benchmark.py
        times it inside numba, without the dispatch). The function makes the step's first force itself, so
        the Neo-Hookean step is timed with the bounds it plans from."""
        if control.attachments.index.size or control.prescribed_index.size:
            raise ValueError("compiled_step covers bodies without attachments or prescribed vertices")
        stiffer, _ = self._stiffer(state, h, False)
        return self._builds[False][1], self._step_args(state, control, self._plan_for(h, control, stiffer),
                                                       self._inv_mass3)

    def step(self, state: State, control: Control, h: float) -> StepInfo:
        common = self._common
        inv_mass3 = self._inv_mass3
        if control.prescribed_index.size:   # fixed vertices are zeroed in the kernel; prescribed ones here
            held = common.apply_prescribed(state, control)
            inv_mass3 = np.where(np.repeat(held, 3), 0.0, inv_mass3)
        choice = self.thread_choice
        parallel = self.threads
        if choice is not None:
            parallel = choice.use_parallel()
            self._step = self._builds[parallel]
            t0 = time.perf_counter()
        self.threaded_steps += parallel
        stiffer, made = self._stiffer(state, h, parallel)
        plan = self._plan_for(h, control, stiffer)
        att = control.attachments
        step_attached, step_free = self._step
        args = self._step_args(state, control, plan, inv_mass3, first_force=not made)
        if att.index.size:
            ok = step_attached(*args, att.index, att.target_u, att.target_v, att.target_a, att.kp, att.kd)
        else:
            ok = step_free(*args)
        if choice is not None:
            choice.record(parallel, time.perf_counter() - t0)
        common.finish(state, h, self.name, checked=ok)
        return self._info
