"""Physics on a thread of its own, handing finished states to the outputs as snapshots. No ROS.

    loop = SimLoop(scene, now=ros_seconds, timer_hz=100.0, max_catchup_steps=250, log=log)
    loop.start()
    loop.take_input(lambda: scene.take_joint_state(...))   # from the subscription callback: queued
    snap = loop.shown()                                     # from the output timers: never half written
    loop.stop()                                             # joins the thread

The step kernel releases the GIL, so a step runs while the executor thread builds markers, computes stress
and records (the small compiled functions around it keep the GIL: numba_config.HOLDS_GIL). The scene is
changed by this thread only: the subscription callback queues each joint-state sample (a bounded queue) and
this thread pushes it into the scene, so no callback waits for a step and no lock is held across one. The
outputs never read the scene's state: finished states are handed over as a ``Snapshot``, a fresh, read-only
copy of the state, put in place by one reference assignment (atomic in Python); the copy being read stays whole
while the next is made. The physics thread only copies: the output side checks each snapshot once before it shows
it (``shown``, ``Snapshot.problem``: Scene.problem_of), so the checks of states nobody shows cost nothing and the
thread's time goes to steps. The step loop's own divergence checks (Scene.advance_to) stay on this thread.

The clock is the scene's physics.clock. Clock "input": each sample is taken by Scene.take_joint_state, which
steps up to its stamp, as a replay of the recorded joint states (replay.py) does, so the replay reproduces
every published state bit for bit. Clock "wall" steps up to the clock whenever a joint state arrives or
1 / timer_hz has passed, at most 0.7 / timer_hz per batch, in slow motion up to ``max_catchup_steps`` behind; it
hands over the first state that saw each input, and the state a batch ends on at most once per 1 / timer_hz
(``_follow_clock``).

A divergence resets the body. Any other exception in a step is logged, counted in ``crashes``
and ``error``, and the body is reset; after ``MAX_CRASHES_IN_A_ROW`` crashes with no good step between them
the thread stops (``stopped``), the node keeps running and reports it, and ``stop()`` still returns.
"""
from __future__ import annotations

import sys
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .fem.stability import DivergenceError, StabilityError

MAX_CRASHES_IN_A_ROW = 5
GIL_SWITCH_INTERVAL = 2e-4     # s: see SimLoop.start
INPUT_QUEUE = 1024          # samples waiting for the physics thread (~8 s of a 120 Hz stream)
STAGES = ("inputs", "skeleton", "physics", "checks", "snapshot", "output_checks", "stress", "markers", "cloud",
          "diagnostics", "recording")
THREAD_STAGES = ("inputs", "skeleton", "physics", "checks", "snapshot")     # the physics thread's own work


_UNCHECKED = object()


@dataclass(eq=False)
class Snapshot:
    """A finished state, copied: what every output of one tick shows, once ``problem()`` has passed it.
    ``inputs_used``: how many accepted joint states the steps that made it had seen (the latency's reference).
    ``u`` and ``v`` are read-only views of private copies; the compiled checks and the stress read the copies (a
    read-only array is another type to numba, compiled once more for nothing)."""
    sim_time: float
    u: np.ndarray
    v: np.ndarray
    steps: int
    inputs_used: int
    taken_at: float                      # time.perf_counter()
    _check: Callable | None = field(default=None, repr=False)     # (u, v) -> problem (Scene.output_check)
    _own: tuple = field(default=(), repr=False)                   # the writable copies behind u and v
    _problem: object = field(default=_UNCHECKED, repr=False)
    _stress: object = field(default=None, repr=False)

    @classmethod
    def of_scene(cls, scene, inputs_used: int, taken_at: float) -> "Snapshot | None":
        """The hand-over of the scene's current state: copies of u and v (their read-only views as ``u``, ``v``)
        with the check of ``Scene.output_check``; None while the body is not placed (Scene.placement_problem).
        What SimLoop gives its outputs, and what benchmarks/physics_alone.py times."""
        if scene.placement_problem() is not None:
            return None
        u, v = scene.state.u.copy(), scene.state.v.copy()
        snap = cls(scene.sim_time, u.view(), v.view(), scene.steps_done, inputs_used, taken_at,
                   _check=scene.output_check(), _own=(u, v))
        snap.u.flags.writeable = snap.v.flags.writeable = False      # handed over: nobody writes it again
        return snap

    def problem(self, stages: "StageClock | None" = None) -> str | None:
        """Why this state must not be published or recorded, or None: its check, run once, by the first output
        that asks (on the output side: the physics thread only copies)."""
        if self._problem is _UNCHECKED:
            t0 = time.perf_counter()
            self._problem = None if self._check is None else self._check(*self._own)
            if stages is not None:
                stages.add("output_checks", time.perf_counter() - t0)
        return self._problem

    def stress(self, model, material, stages: "StageClock | None" = None):
        """The stress field of this state by the running material model (MaterialModel.stress), computed once
        (the surface colours and the cloud share it)."""
        if self._stress is None:
            t0 = time.perf_counter()
            self._stress = material.stress(model, self._own[0])
            if stages is not None:
                stages.add("stress", time.perf_counter() - t0)
        return self._stress


class StageClock:
    """Seconds spent per stage (wall time inside it), for the busy share of each: seconds per wall second,
    1.0 being one core's worth. Each stage is added to from one thread only."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.totals = dict.fromkeys(STAGES, 0.0)
        self._mark = (self.t0, dict(self.totals), time.process_time())

    def add(self, stage: str, seconds: float) -> None:
        self.totals[stage] += seconds

    def shares(self) -> dict[str, float]:
        """Busy share per stage since the previous call (or the start), and ``process`` (the whole process's
        CPU time per wall second: up to the number of cores)."""
        now, cpu = time.perf_counter(), time.process_time()
        t_prev, prev, cpu_prev = self._mark
        totals = dict(self.totals)
        self._mark = (now, totals, cpu)
        dt = max(now - t_prev, 1e-9)
        out = {k: (totals[k] - prev[k]) / dt for k in STAGES}
        out["process"] = (cpu - cpu_prev) / dt
        return out


class LatencyMeter:
    """Joint-state arrival -> first surface Marker published whose state had seen it [s].

    Arrivals are numbered in the order they were accepted; a published marker whose snapshot saw the first
    ``used`` of them closes every one still open up to ``used``. The last ``keep`` latencies are kept for the
    percentiles (bounded memory); the maximum and the count cover the whole run. Beside it, arrival -> first
    snapshot handed over that had seen it (``latency_state_*``: the physics thread's share; the rest is the
    wait for the marker timer and the marker's making)."""

    def __init__(self, keep: int = 20000):
        self._open: deque[tuple[int, float]] = deque(maxlen=keep)
        self._open_state: deque[tuple[int, float]] = deque(maxlen=keep)
        self._done: deque[float] = deque(maxlen=keep)
        self._state: deque[float] = deque(maxlen=keep)
        self.count = 0
        self.max = 0.0
        self._lock = threading.Lock()

    def arrived(self, seq: int, t: float) -> None:
        with self._lock:
            self._open.append((seq, t))
            self._open_state.append((seq, t))

    def handed_over(self, used: int, t: float) -> None:
        """A snapshot that had seen ``used`` arrivals was handed over at ``t``."""
        with self._lock:
            while self._open_state and self._open_state[0][0] <= used:
                self._state.append(t - self._open_state.popleft()[1])

    def published(self, used: int, t: float) -> None:
        """A marker of a snapshot that had seen ``used`` arrivals was published at ``t``."""
        with self._lock:
            while self._open and self._open[0][0] <= used:
                lat = t - self._open.popleft()[1]
                self._done.append(lat)
                self.count += 1
                self.max = max(self.max, lat)

    def restart(self) -> None:
        """Forget the latencies measured so far (a timed run starts); arrivals still open stay open."""
        with self._lock:
            self._done.clear()
            self._state.clear()
            self.count = 0
            self.max = 0.0

    def percentiles(self) -> dict[str, float]:
        """p50, p99 (of the last ``keep``) and max [ms] to the marker, p50 and p99 to the snapshot; zeros
        before the first."""
        with self._lock:
            done = np.fromiter(self._done, float, len(self._done))
            state = np.fromiter(self._state, float, len(self._state))
        p50, p99 = np.percentile(done, [50, 99]) * 1e3 if done.size else (0.0, 0.0)
        s50, s99 = np.percentile(state, [50, 99]) * 1e3 if state.size else (0.0, 0.0)
        return {"latency_p50_ms": float(p50), "latency_p99_ms": float(p99), "latency_max_ms": self.max * 1e3,
                "latency_state_p50_ms": float(s50), "latency_state_p99_ms": float(s99)}


class SimLoop:
    """The physics thread of one scene; see the module docstring."""

    _running = 0                # loops started and not yet stopped in this process (see start)
    _switch_before: float | None = None     # the process's switch interval while two or more loops run
    _switch_lock = threading.Lock()

    def __init__(self, scene, now: Callable[[], float], timer_hz: float, max_catchup_steps: int,
                 log: Callable[[str, str], None], name: str = "physics",
                 timer: Callable[[], float] = time.perf_counter):
        clock = scene.config.physics.clock
        if clock not in ("wall", "input"):
            raise ValueError(f"physics.clock {clock!r} is not 'wall' or 'input'")
        self.scene = scene
        self.clock = clock
        self.now = now
        self.period = 1.0 / float(timer_hz)
        self.max_steps = int(max_catchup_steps)
        self.log = log                                   # log(level, text), level "error" | "warning" | "info"
        self.timer = timer                               # seconds: what the wall clock's batches and hand-overs
                                                         # are timed by (a test passes a fake clock)
        self.stages = StageClock()
        self.latency = LatencyMeter()
        self.snapshot: Snapshot | None = None
        self.divergences = 0
        self.crashes = 0
        self.error: str | None = None                    # the last crash, for the diagnostics
        self.error_at = float("-inf")                    # and when (time.perf_counter())
        self.stopped = False                             # the thread gave up (MAX_CRASHES_IN_A_ROW)
        self.unplaced = 0                                # states not handed over: Scene.placement_problem
        self.refused = 0                                 # states handed over that failed Snapshot.problem
        self._shown: Snapshot | None = None              # the newest snapshot that passed (output side)
        self._refused_last: Snapshot | None = None
        self._shown_lock = threading.Lock()              # shown(): the executor's outputs and any other reader
        self.queue_full = 0                              # samples refused: INPUT_QUEUE of them waiting
        self._accepted = 0                               # accepted inputs pushed so far (the latency's numbering)
        self._seen = 0                                   # of them, those a step has seen
        self._queue: deque = deque()
        self._wake = threading.Condition()
        self._pending = False                            # an input arrived since the thread last looked
        self._taken = (-1, float("-inf"))                # (steps_done, timer()) of the last state looked at
                                                         # for a snapshot (handed over or refused)
        self._stop = threading.Event()
        self._in_a_row = 0
        self._headroom = (0, 0.0, 0.0)                   # (steps, CPU s, busy s) at the previous headroom() call
        self._busy = 0.0                                 # the thread's wall seconds outside _wait
        self._cpu = 0.0                                  # the thread's CPU seconds
        self._waited = (0.0, 0.0)                        # of an iteration of _run, (wall, CPU) seconds in _wait
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._counted = False                            # counted in SimLoop._running (start, until stop)

    # -- control ---------------------------------------------------------------------------------
    def start(self) -> None:
        # Physics threads of several bodies in one process hand the GIL back and forth around their nogil
        # kernels; at Python's default switch interval (5 ms) a thread back from its kernel waits up to that long
        # while another runs Python: two bodies in one process ran at a real-time factor of 0.38 each, 0.57-0.68
        # at 0.2 ms (realtime_benchmark --bodies 2). One body keeps the default, under which it kept real time;
        # the interval the process had comes back when fewer than two loops run (stop).
        with SimLoop._switch_lock:
            SimLoop._running += 1
            if SimLoop._running == 2:
                SimLoop._switch_before = sys.getswitchinterval()
                sys.setswitchinterval(min(SimLoop._switch_before, GIL_SWITCH_INTERVAL))
        self._counted = True
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> bool:
        """Stop and join the thread; True if it ended within ``timeout`` (a step is milliseconds)."""
        with SimLoop._switch_lock:
            if self._counted:
                self._counted = False
                SimLoop._running -= 1
                if SimLoop._running == 1 and SimLoop._switch_before is not None:
                    sys.setswitchinterval(SimLoop._switch_before)
                    SimLoop._switch_before = None
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    @property
    def waiting(self) -> int:
        """Joint-state samples queued for the physics thread and not yet taken (at most INPUT_QUEUE)."""
        return len(self._queue)

    # -- inputs ----------------------------------------------------------------------------------
    def take_input(self, push: Callable[[], None]) -> None:
        """Hand one joint-state sample over: ``push()`` gives it to the scene (Scene.take_joint_state), on the
        physics thread (the callback never waits for a step). Clock "wall": every sample queued is pushed before
        the next step; clock "input": one sample is taken, with the steps up to its stamp, then the next."""
        if len(self._queue) >= INPUT_QUEUE:
            self.queue_full += 1
            self.log("warning", f"joint state dropped: {INPUT_QUEUE} samples wait for physics "
                                f"({self.queue_full} dropped so far); physics cannot keep up with the input rate")
            return
        self._queue.append((push, time.perf_counter()))
        with self._wake:
            self._pending = True
            self._wake.notify()

    def _push_next(self) -> None:
        """The oldest queued sample given to the scene; its time less the steps it made goes to the inputs
        stage (the steps' to skeleton and physics: _timed)."""
        push, arrived = self._queue.popleft()
        t = time.perf_counter()
        s = self.scene
        before, wall0 = s.inputs.accepted, s.step_wall_s
        try:
            push()
        finally:                                    # counted also when the steps after the push diverged
            if s.inputs.accepted > before:
                self._accepted += 1
                self.latency.arrived(self._accepted, arrived)
            self.stages.add("inputs", time.perf_counter() - t - (s.step_wall_s - wall0))

    # -- the thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            t0, cpu0, self._waited = time.perf_counter(), time.thread_time(), (0.0, 0.0)
            try:
                if self.clock == "input":
                    self._follow_inputs()
                else:
                    self._follow_clock()
            except (DivergenceError, StabilityError) as exc:
                self.divergences += 1
                self.log("error", f"{exc}; the body is reset ({self.divergences} resets so far)")
                try:
                    self._reset()
                except Exception as again:  # noqa: BLE001 (a reset that fails is a failure: counted, the thread goes on)
                    self._crashed(again)
            except Exception as exc:  # noqa: BLE001 (any failure of a step: report it, reset, go on or stop)
                self._crashed(exc)
            self._busy += time.perf_counter() - t0 - self._waited[0]
            self._cpu += time.thread_time() - cpu0 - self._waited[1]

    def _wait(self, timeout: float | None = None) -> None:
        """Until an input arrives, ``timeout`` or 1 / timer_hz passes, or stop."""
        t0, cpu0 = time.perf_counter(), time.thread_time()
        with self._wake:
            if not self._queue and not self._pending and not self._stop.is_set():
                self._wake.wait(self.period if timeout is None else min(timeout, self.period))
            self._pending = False
        wall, cpu = self._waited
        self._waited = (wall + time.perf_counter() - t0, cpu + time.thread_time() - cpu0)

    def _follow_inputs(self) -> None:
        """Clock "input": each sample taken with the steps up to its stamp (Scene.take_joint_state), as
        replay.py does."""
        if not self._queue:
            self._wait()
            return
        n = self._timed(self._push_next)
        used = self._accepted
        if n or self.snapshot is None:
            self._take_snapshot(used)

    def _follow_clock(self) -> None:
        """Clock "wall": the queued inputs pushed, then steps up to now, until none is due or the batch's
        time is up. The first state that saw a new input is handed over at once, and an input no step has
        seen yet wakes the thread when the next step is due (not a timer period later): so from an input's
        arrival to a snapshot that used it takes about a step, whatever else the batch does. The state a
        batch ends on is handed over too, unless the last hand-over is less than a timer period old: then the
        next input's state comes first, or a later batch's end (the thread wakes at least once a period), so
        the outputs never show a state more than about a period and a batch older than physics. A streamed
        body hands over a state per input, not two: half the snapshots and their checks."""
        deadline = self.timer() + 0.7 * self.period
        stepped, due_in = 0, None
        scene = self.scene
        while not self._stop.is_set():
            while self._queue:
                self._push_next()
            target = scene.wall_target(self.now())
            if scene.sim_time is not None and scene.steps_due(target) <= 0:
                if self._accepted > self._seen:
                    due_in = scene.sim_time + scene.h - target
                break
            fresh = self._accepted > self._seen
            used = self._seen = self._accepted
            # deadline 0: advance_to does one step (or drops the gap past max_steps, or starts the clock)
            stepped += self._timed(lambda: scene.advance_to(target, self.max_steps, deadline=0.0)) or 1
            if fresh:
                self._take_snapshot(used)
            if self.timer() > deadline:
                break
        if self._taken[0] != scene.steps_done and self.timer() - self._taken[1] >= self.period:
            self._take_snapshot(self._seen)
        if stepped == 0 or self.timer() <= deadline:
            self._wait(due_in)

    def _timed(self, advance: Callable[[], object]) -> int:
        """Run ``advance`` (steps of the scene); its time goes to the skeleton, physics and checks stages."""
        s = self.scene
        steps0, wall0, skel0, check0 = s.steps_done, s.step_wall_s, s.skeleton_wall_s, s.check_wall_s
        try:
            advance()
        finally:                                    # a check that found a divergence took its time too
            self.stages.add("checks", s.check_wall_s - check0)
        n = s.steps_done - steps0
        if n:
            skel = s.skeleton_wall_s - skel0
            self.stages.add("skeleton", skel)
            self.stages.add("physics", s.step_wall_s - wall0 - skel)
            self._in_a_row = 0
        return n

    def _take_snapshot(self, used: int) -> None:
        """Hand the scene's state over (a copy, checked by the output side: Snapshot.problem), unless the body
        is not placed on its skeleton (Scene.placement_problem)."""
        t = time.perf_counter()
        s = self.scene
        self._taken = (s.steps_done, self.timer())
        snap = Snapshot.of_scene(s, used, t)
        if snap is not None:
            self.snapshot = snap
            self.latency.handed_over(used, time.perf_counter())
        elif s.sim_time is not None:
            self.unplaced += 1
        self.stages.add("snapshot", time.perf_counter() - t)

    def shown(self) -> Snapshot | None:
        """The state the outputs show: the newest snapshot if it passes its check (Snapshot.problem, run here
        once per snapshot), else the last one that passed (None before any). A snapshot that fails is counted
        once in ``refused``. Called from the output side, not from the physics thread."""
        with self._shown_lock:
            snap = self.snapshot
            if snap is None or snap is self._shown or snap is self._refused_last:
                return self._shown
            if snap.problem(self.stages) is None:
                self._shown = snap
            else:
                self._refused_last = snap
                self.refused += 1
            return self._shown

    @property
    def unpublishable(self) -> int:
        """States the outputs did not get: not placed on the skeleton, or handed over and refused by its check."""
        return self.unplaced + self.refused

    def _reset(self) -> None:
        self.scene.reset()

    def _crashed(self, exc: BaseException) -> None:
        self.crashes += 1
        self._in_a_row += 1
        self.error = f"{type(exc).__name__}: {exc}"
        self.error_at = time.perf_counter()
        trace = "".join(traceback.format_exception(exc)).rstrip()
        if self._in_a_row >= MAX_CRASHES_IN_A_ROW:
            self.stopped = True
            self._stop.set()
            self.log("error", f"physics failed {self._in_a_row} times in a row and has stopped (the node keeps "
                              f"running without new states; restart it): {self.error}\n{trace}")
            return
        self.log("error", f"physics step failed ({self.crashes} failures so far); the body is reset: {self.error}"
                          f"\n{trace}")
        try:
            self._reset()
        except Exception as again:  # noqa: BLE001 (a reset that fails too counts as the next failure)
            self._crashed(again)

    # -- measurements ----------------------------------------------------------------------------
    def busy_s(self) -> float:
        """Seconds the physics thread has worked: its wall time outside its waits for inputs and the clock (the
        THREAD_STAGES, and the loop's own bookkeeping between them), including the time it waited for the GIL
        or for a core."""
        return self._busy

    def cpu_s(self) -> float:
        """CPU seconds the physics thread has used (what its work costs when nothing else runs)."""
        return self._cpu

    def headroom(self) -> dict[str, float]:
        """Over the steps since the previous call, simulated seconds per second of the physics thread's work:
        ``alone`` per CPU second (``cpu_s``: what the thread would sustain with a core and the GIL to itself),
        ``in_node`` per busy wall second (``busy_s``: with the waits for the GIL, held by the executor thread's
        Python between the numba kernels, and for a core). Zeros before any step."""
        steps, cpu, busy = self.scene.steps_done, self._cpu, self._busy
        d_steps, d_cpu, d_busy = steps - self._headroom[0], cpu - self._headroom[1], busy - self._headroom[2]
        if d_steps <= 0 or d_cpu <= 0 or d_busy <= 0:
            return {"alone": 0.0, "in_node": 0.0}
        self._headroom = (steps, cpu, busy)
        sim = d_steps * self.scene.h
        return {"alone": sim / d_cpu, "in_node": sim / d_busy}
