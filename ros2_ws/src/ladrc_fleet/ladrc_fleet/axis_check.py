"""The axis' velocity loop from a run's own ticks: its time constant T1 and gain.

The drive is modelled as in the simulator and ``ladrc identify`` (first order, velocity
mode): ``v[k+1] = a v[k] + b u[k]``, ``a = exp(-h / T1)``, gain ``b / (1 - a)``, with ``u`` the
command of tick k (``FollowStatus.velocity_mm_s``) and ``v`` the encoder's speed. The encoder's
1 µm steps make a one-tick speed too coarse (2 mm/s at 2 kHz), so both sides are averaged over
:data:`WINDOW` ticks: ``v_f[k] = (z[k] - z[k-W]) / (W h)`` and ``u_f`` the mean of the same W
commands; averaging commutes with the linear model, so the same ``a, b`` hold for the averaged
signals. Least squares over the ticks where the controller moves the axis (approach, PID,
LADRC), accumulated as 2 x 2 normal equations: one slice at a time, constant memory.
"""

from __future__ import annotations

import math
from typing import Any

from ladrc_contract.codes import FollowState
import numpy as np

MOVING = (int(FollowState.PREINTERPOLATE), int(FollowState.PID), int(FollowState.LADRC))
WINDOW = 4
"""Ticks the encoder speed and the command are averaged over."""
MIN_ROWS = 200


class AxisCheck:
    """Accumulates the velocity loop's T1 and gain of one bag (``fields``, ``add``, ``result``)."""

    fields = {'follow/status': ('state', 'encoder_mm', 'velocity_mm_s')}

    def __init__(self, h_s: float = 0.0005) -> None:
        self.h = h_s
        self._tail: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._ata = np.zeros((2, 2))
        self._atb = np.zeros(2)
        self.rows = 0

    def add(self, part: dict[str, dict[str, np.ndarray]]) -> None:
        """Take one slice of the bag (``Bag.stream``)."""
        st = part.get('follow/status')
        if st is None or not st['state'].size:
            return
        z = st['encoder_mm'].astype(float)
        u = st['velocity_mm_s'].astype(float)
        moving = np.isin(st['state'].astype(int), MOVING)
        if self._tail is not None:  # the last W ticks of the slice before
            z = np.r_[self._tail[0], z]
            u = np.r_[self._tail[1], u]
            moving = np.r_[self._tail[2], moving]
        w = WINDOW
        self._tail = (z[-w - 1:], u[-w - 1:], moving[-w - 1:])
        if z.size < w + 2:
            return
        vf = (z[w:] - z[:-w]) / (w * self.h)         # vf[i] ends at tick i + w
        uf = np.convolve(u, np.ones(w) / w, 'valid')  # uf[i]: u[i .. i+w-1], ends at i + w - 1
        # v_f[k+1] = a v_f[k] + b u_f[k]: vf[i+1] (ends k+1 = i+w+1) on vf[i], uf[i+1]
        ok = np.convolve(moving.astype(int), np.ones(w + 2, int), 'valid') == w + 2
        n = min(vf.size - 1, uf.size - 1, ok.size)
        y, x0, x1 = vf[1:n + 1], vf[:n], uf[1:n + 1]
        m = ok[:n] & np.isfinite(y) & np.isfinite(x0) & np.isfinite(x1)
        a_ = np.c_[x0[m], x1[m]]
        self._ata += a_.T @ a_
        self._atb += a_.T @ y[m]
        self.rows += int(m.sum())

    def result(self) -> dict[str, Any]:
        """Return ``axis_t1_ms`` and ``axis_gain`` (None: too little motion)."""
        if self.rows < MIN_ROWS or abs(np.linalg.det(self._ata)) < 1e-12:
            return {'axis_t1_ms': None, 'axis_gain': None}
        a, b = np.linalg.solve(self._ata, self._atb)
        if not 0.0 < a < 1.0:
            return {'axis_t1_ms': None, 'axis_gain': None}
        return {'axis_t1_ms': -self.h / math.log(a) * 1e3, 'axis_gain': b / (1.0 - a)}
