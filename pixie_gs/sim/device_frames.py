"""Frames of a batched simulation with nothing read back until the end (GPU: one graph per frame).

Why: BatchedSolver.step_frame ends every frame in a device sync — the host needs the runs'
fastest speeds to plan the next frame's substeps (CFL), the guard's counts and the positions —
and the GPU idles while the host plans, uploads and launches the next frame. Here the plan
(batch_kernels.plan_frame: _plan's float64 operations, on the device), the substep loop (a
device-side while loop: a CUDA conditional graph node), the statistics, the guard and the copy of
the tracked points into a history all stay on the device; on a GPU each frame is ONE captured
graph, launched back to back, and the host waits once at the end. Same substeps, dt and
arithmetic as step_frame: on the CPU (no capture: the same launches, the loop read on the host)
the results are bit-for-bit step_frame's (tests/test_sim_batched.py).
Frames with an impulse still pending stay with step_frame (its kick is applied between substeps).
"""
from __future__ import annotations

import time

import numpy as np
import warp as wp

from . import batch_kernels as bk
from .solver import FAR


def device_loop_available(device: str) -> bool:
    """CPU: always (a host loop, for tests); CUDA: when conditional graph nodes are (CUDA 12.4+)."""
    return device == "cpu" or bool(wp.is_conditional_graph_supported())


class DeviceFrames:
    """Runs a BatchedSolver's next frames on the device; `slots` (P,) are the particle slots whose
    positions every frame keeps, `frames` the history's rows (a frame's row is its number)."""

    def __init__(self, solver, frame_dt_s: float, slots: np.ndarray, frames: int) -> None:
        d = solver.device
        self.solver = solver
        self.frame_dt = float(frame_dt_s)
        k = solver.k
        s = solver.scene.solver
        f64 = wp.float64
        self.c_static = wp.array(solver._c_static, dtype=f64, device=d)
        self.has_snow = wp.array(solver._has_snow.astype(np.int32), dtype=wp.int32, device=d)
        self.accel_dt = wp.array(solver._accel * self.frame_dt, dtype=f64, device=d)  # as _plan computes it
        self.v_limit64 = wp.zeros(k, dtype=f64, device=d)
        self.over_budget = wp.zeros(k, dtype=wp.int32, device=d)
        self.last_dt = wp.array(np.array([run.dt for run in solver._runs], np.float64), dtype=f64, device=d)
        self.n_max = wp.zeros(1, dtype=wp.int32, device=d)
        self.total = wp.zeros(1, dtype=wp.int32, device=d)   # substeps launched (the frames' n_max summed)
        self.cond = wp.zeros(1, dtype=wp.int32, device=d)
        self.frame = wp.zeros(1, dtype=wp.int32, device=d)
        self.err_frame = wp.zeros(k, dtype=wp.int32, device=d)
        self.err_counts = wp.zeros((k, solver.bad.shape[1]), dtype=wp.int32, device=d)
        self.err_limit = wp.zeros(k, dtype=f64, device=d)
        self.slots = wp.array(np.asarray(slots, np.int32), dtype=wp.int32, device=d)
        self.history = wp.zeros((frames, len(slots)), dtype=wp.vec3, device=d)
        self._plan = wp.launch(bk.plan_frame, dim=1, device=d, record_cmd=True,
                               inputs=[solver.maxima, solver.alive_flag, self.c_static, self.has_snow, self.accel_dt,
                                       self.frame_dt, s.cfl * solver.dx, s.velocity_cfl * solver.dx, solver.dx,
                                       s.max_substeps_per_frame, FAR, solver.n_sub, solver.dt_run, solver.dt_run64,
                                       solver.v_limit, self.v_limit64, self.over_budget, self.last_dt,
                                       solver.substep, self.n_max, self.cond, self.total])
        self._next = wp.launch(bk.next_substep, dim=1, device=d, record_cmd=True,
                               inputs=[solver.substep, self.n_max, self.cond])
        self._guard = wp.launch(bk.guard_frame, dim=1, device=d, record_cmd=True,
                                inputs=[solver.bad, solver.alive_flag, self.frame, self.v_limit64, self.err_frame,
                                        self.err_counts, self.err_limit])
        self._record = wp.launch(bk.record_points, dim=len(slots), device=d, record_cmd=True,
                                 inputs=[solver.state.x, self.slots, self.frame, self.history])
        self._end = wp.launch(bk.end_frame, dim=1, device=d, record_cmd=True,
                              inputs=[self.frame, solver.frame_start, self.frame_dt])
        self.graph = None
        if d != "cpu":
            wp.capture_begin(device=d, force_module_load=True)
            try:
                self._one_frame()
            finally:
                self.graph = wp.capture_end(device=d)

    def _substep(self) -> None:
        sv = self.solver
        sv._p2g.launch()
        sv._grid.launch()
        sv._g2p.launch()
        self._next.launch()

    def _one_frame(self) -> None:
        """A frame's launches (captured once on a GPU): plan, substeps, statistics, guard, history."""
        sv = self.solver
        self._plan.launch()
        wp.capture_while(self.cond, self._substep)
        sv.maxima.zero_()
        sv.bad.zero_()
        sv._stats_launch.launch()
        self._guard.launch()
        self._record.launch()
        self._end.launch()

    def run(self, count: int) -> np.ndarray:
        """Advance the solver by `count` frames → the kept positions (count, P, 3) float32 world m
        of those frames; afterwards the solver's host state (alive, errors, over-budget runs, substep
        counts, dt, time, statistics) is as if step_frame had made them."""
        sv = self.solver
        if sv._pending:
            raise RuntimeError("an impulse is still pending: step_frame applies it")
        if sv._stats is None:
            sv._stats = sv._reduce(np.full(sv.k, FAR))  # the first frame's plan needs statistics
        sv._upload(sv.alive_flag, sv._alive.astype(np.int32))  # a run the last guard stopped
        first = sv.frame
        self.frame.fill_(first)
        self.total.zero_()
        sv.frame_start.fill_(sv.time_s)
        if sv.device == "cpu":  # the grid launch covers the whole grid (step_frame narrows it per substep)
            sv._grid.set_dim((sv.k,) + tuple(sv.dims))
            sv._grid.set_param_at_index(sv._box_arg, wp.vec3i(0, 0, 0))
        times = []
        for _ in range(count):
            if self.graph is not None:
                wp.capture_launch(self.graph)
            else:
                self._one_frame()
            sv.time_s = sv.time_s + self.frame_dt  # the host's own clock, as step_frame keeps it
            times.append(sv.time_s)
        sv.frame = first + count
        sv.state.time_s = sv.time_s
        self._finish(first, times)
        return self.history.numpy()[first + 1:first + 1 + count]

    def _finish(self, first: int, times: list[float]) -> None:
        """Bring the device's per-run outcome back into the solver's host bookkeeping (one sync)."""
        sv = self.solver
        start = time.perf_counter()
        wp.synchronize_device(sv.device)
        sv.wait_s += time.perf_counter() - start
        sv.substeps_total += int(self.total.numpy()[0])
        alive = sv.alive_flag.numpy().astype(bool)
        over = self.over_budget.numpy().astype(bool)
        n_sub = sv.n_sub.numpy()
        last_dt = self.last_dt.numpy()
        err_frame = self.err_frame.numpy()
        err_counts = self.err_counts.numpy()
        err_limit = self.err_limit.numpy()
        for r, run in enumerate(sv._runs):
            run.substeps_last_frame = int(n_sub[r])
            if run.alive and over[r]:
                sv._stop(r)
                run.over_budget = True
            elif run.alive and err_frame[r] > 0:
                f = int(err_frame[r])
                sv._diverged(r, err_counts[r], f, times[f - first - 1], float(err_limit[r]))
            run.dt = float(last_dt[r])  # updated on the device only where a run was planned, as step_frame does
            assert run.alive == alive[r]
        sv._uploaded.clear()  # the device changed n_sub, dt, v_limit and alive itself
        sv._stats = (sv.maxima.numpy().astype(np.float64), sv.bad.numpy().copy())
        sv._x_frame = -1      # positions are read from the device again
