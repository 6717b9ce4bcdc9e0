"""Physical success checks: is the object up, who holds it, for how long.

A :class:`HoldMonitor` samples one object every few physics steps (height above the table, the arms
whose two fingers press on it, the arms touching it at all, table contact). The verdicts are computed
from those samples: the longest stretch of time during which a condition held without interruption.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HoldMonitor", "HoldSample", "HoldVerdict"]

FELL_OFF = 0.05  # m below its start height: the object has left the table top (fell off its edge)


@dataclass
class HoldSample:
    t: float
    rise: float  # m above the object's starting height
    holders: frozenset  # arms whose both fingers press on the object
    touching: frozenset  # arms with any link in contact with the object
    on_table: bool


@dataclass
class HoldVerdict:
    """Outcome of a check.

    Attributes:
        ok: the condition held for the required time.
        held_s: longest uninterrupted time the condition held (s).
        max_rise: highest rise of the object during the watch (m).
        start, end: the stretch's simulated times (s), or None.
        detail: one sentence for people.
    """

    ok: bool
    held_s: float
    max_rise: float
    start: float | None = None
    end: float | None = None
    detail: str = ""


class HoldMonitor:
    """Watch one object in a :class:`~._world.PreviewWorld` (register with ``world.add_listener``).

    Args:
        world: the world.
        obj: the :class:`~._world.SimObject` to watch.
        every: sample every ``every`` physics steps.
        min_force: N per finger for an arm to count as holding.
        grip: arm name -> ``"pinch"`` (both fingers must press: the default) or ``"push"`` (the gripper presses
            the object with >= 4 x min_force N in total: two grippers squeezing it between them).
    """

    def __init__(self, world, obj, every: int = 4, min_force: float = 0.5, grip: dict | None = None):
        self.world, self.obj, self.every, self.min_force = world, obj, int(every), float(min_force)
        self.grip = dict(grip or {})
        self.h0 = world.height(obj)
        self.samples: list[HoldSample] = []
        self._k = 0

    def __call__(self, world) -> None:
        self._k += 1
        if self._k % self.every:
            return
        self.samples.append(self.sample())

    def sample(self) -> HoldSample:
        w, b = self.world, self.obj.body
        holders = frozenset(n for n, a in w.arms.items()
                            if (a.presses(b, 4 * self.min_force) if self.grip.get(n) == "push" else a.holds(b, self.min_force)))
        touching = frozenset(n for n, a in w.arms.items() if a.touches(b))
        return HoldSample(w.time, w.height(self.obj) - self.h0, holders, touching, w.on_table(self.obj))

    def reset_window(self) -> None:
        """Forget the samples so far (the next check only looks at what follows)."""
        self.samples.clear()

    def _longest(self, pred, since: float = -np.inf) -> tuple[float, float | None, float | None]:
        best, cur = 0.0, None
        bs = be = None
        for s in self.samples:
            if s.t < since:
                continue
            if pred(s):
                if cur is None:
                    cur = s.t
                dur = s.t - cur
                if dur >= best:
                    best, bs, be = dur, cur, s.t
            else:
                cur = None
        return best, bs, be

    def lifted_and_held(self, arms: set[str], rise: float = 0.10, hold_s: float = 2.0, since: float = -np.inf,
                        exclusive: bool = False) -> HoldVerdict:
        """The object stayed ``rise`` m above its start, off the table, held by every arm in ``arms``
        (and, with ``exclusive``, touched by no other arm) for ``hold_s`` s without interruption."""
        arms = frozenset(arms)

        def pred(s: HoldSample) -> bool:
            ok = s.rise >= rise and not s.on_table and arms <= s.holders
            if exclusive:
                ok = ok and s.touching <= arms
            return ok

        held, a, b = self._longest(pred, since)
        win = [s for s in self.samples if s.t >= since]
        max_rise = max((s.rise for s in win), default=0.0)
        ok = held + 1e-9 >= hold_s - self.every * self.world.dt
        who = " and ".join(sorted(arms))
        if ok:
            detail = f"held by {who}{' only' if exclusive else ''}, {max_rise * 100:.1f} cm up, for {held:.1f} s"
        else:
            last = win[-1] if win else None
            why = []
            if last is not None:
                if last.on_table:
                    why.append("the object is back on the table")
                missing = arms - last.holders
                if missing:
                    why.append(f"not held by {', '.join(sorted(missing))}")
                if exclusive and not last.touching <= arms:
                    why.append(f"still touched by {', '.join(sorted(last.touching - arms))}")
            if last is not None and last.rise < -FELL_OFF:  # below the table top: off its edge
                why.append(f"the object fell off the table ({-last.rise * 100:.0f} cm below where it started)")
            elif max_rise < rise:
                why.append(f"rose only {max_rise * 100:.1f} cm (needs {rise * 100:.0f} cm)")
            detail = (f"held as required for {held:.1f} s of {hold_s:.1f} s"
                      + (": " + "; ".join(why) if why else ""))
        return HoldVerdict(bool(ok), float(held), float(max_rise), a, b, detail)
