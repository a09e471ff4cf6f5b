"""The plan's clock (issue 15): a mission's plan runs on one clock that waits for the late.

A plan (paper 000 §IV: paths in time, conflict-free at equal times) keeps the bodies apart only
while every vehicle is where it says at the same time. Run on the wall clock, one vehicle that
falls behind (a turn in place that takes longer, a stop on a stale pose, a starved loop) meets the
others on time at the plan's margin: the contacts of the 32-vehicle soaks were such meetings, a
late vehicle and an on-time one passing at the plan's 3 cm (docs/reliability.md). Here the plan's
time is `now - t0 - delay`: each executor slows it while one of its vehicles lags its reference
(`pace`, 1 up to `slow_from` x the margin, 0 from `stop_at` x: `pace_for`), and every executor and
the mission keep the same delay: an executor adds its own waiting on top of the largest delay it
has heard (`PlanClock.wait`) and tells the others (`PlanDelay`, `mission/<id>/delay`), who take the
largest (`hear`; two executors waiting at once add their wait once). While a heard pace below 1 is
fresh, the delay is carried forward at that pace (`behind`), so the others slow at once, not a
message later. An executor whose loop runs late (a starved process) lets the clock run at most
`max_step_s` a cycle: its vehicles went unwatched meanwhile, and the plan waits for them (in the
first 32-vehicle soak with the clock, drivers stopped on stale poses were still held as left
behind, their references 6 cm on: a starved loop's late cycle moving the clock on in one step is
the likely way, not traced). The plan's time an executor gives its vehicles never goes back: a larger
delay heard stands it still until the wall clock has caught up. This is the coarsest form of executing a plan by the order in which vehicles pass
each place (an action dependency graph, Hönig et al., RA-L 2019): every vehicle waits for every
late one, not only for those whose places it shares; delays cost the whole fleet time, never a
contact. A vehicle that keeps the clock waiting too long is held like one the tracking guard
holds (`ClockParams.max_wait_s`), and the mission plans around it.

An executor whose commands come late slows the clock too (`latency_pace`): at a pose-to-command
latency (its recent p99) above `latency_s` the plan runs at `latency_s / latency` of its pace, so a
vehicle covers no more of its plan within its loop's latency than it does at `latency_s`, and a
stop (the proximity stop, a hold) takes effect as near as it would on a healthy loop. A machine too
loaded for its fleet thereby moves the fleet more slowly instead of closing distances it cannot
watch (32-vehicle soaks of 2026-12-06 on a slow hour: p99 130-220 ms, two vehicles stopped short of
each other 243-400 ms late and touched)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ClockParams:
    """slow_from, stop_at: a vehicle's distance from its reference, in margins
    (`VehicleModel.margin`), at which it starts to slow the plan's clock and at which it stops it
    (the plan keeps a margin between bodies, each vehicle may use half of it); fresh_s: a heard pace
    counts this long after it was sent (executors send theirs every cycle while it is below 1);
    max_wait_s: a vehicle that has kept the clock below full pace this long is held (its own loop
    cannot catch up: the mission plans around it); max_step_s: the most the clock runs in one cycle
    of an executor (the rest of a late cycle counts as waiting); latency_s, latency_floor: an
    executor whose pose-to-command latency is above `latency_s` (s) runs its missions' clocks at
    `latency_s / latency`, never slower than `latency_floor` (`latency_pace`; the soak's p99 on a
    loaded but healthy machine is 30-80 ms; a mission lets its clock wait up to its plan's length,
    `MissionRunner.end_reason`, so at half pace a whole mission still fits); enabled False: the
    plan runs on the wall clock (nothing waits)."""

    slow_from: float = 0.5
    stop_at: float = 1.0
    fresh_s: float = 0.1
    max_wait_s: float = 5.0
    max_step_s: float = 0.05
    latency_s: float = 0.15
    latency_floor: float = 0.5
    enabled: bool = True


def pace_for(error: float, margin: float, params: ClockParams) -> float:
    """The pace (0-1) at which a vehicle `error` m from its reference lets the plan's clock run."""
    if margin <= 0.0 or not params.enabled:
        return 1.0
    x = error / margin
    if x <= params.slow_from:
        return 1.0
    if x >= params.stop_at:
        return 0.0
    return (params.stop_at - x) / (params.stop_at - params.slow_from)


def latency_pace(latency: float, params: ClockParams) -> float:
    """The pace (`latency_floor`-1) at which an executor whose commands come `latency` s after the
    poses they use lets its missions' clocks run: the distance a vehicle covers within the latency
    stays what it is at `latency_s`."""
    if not params.enabled or latency <= params.latency_s:
        return 1.0
    return max(params.latency_s / latency, params.latency_floor)


class PlanClock:
    """One mission's plan clock as one executor (or the mission) keeps it: how far it stands behind
    the wall clock (`delay`, s, never less), and the paces heard from the others."""

    def __init__(self, params: ClockParams = ClockParams()) -> None:
        self.params = params
        self.delay = 0.0
        """The largest delay heard or reached by waiting here (s)."""
        self._heard: dict[str, tuple[float, float, float]] = {}  # source -> (delay, pace, sent)
        self._last: float | None = None
        self._given: tuple[float, float] | None = None  # (when, delay) last given by `behind`
        self.waited = 0.0
        """What the last `wait` added to the delay (s)."""

    def hear(self, source: str, delay: float, pace: float, sent: float) -> None:
        """Another executor's clock: `delay` at wall time `sent`, running at `pace` since."""
        known = self._heard.get(source)
        if known is None or sent >= known[2]:
            self._heard[source] = (delay, min(max(pace, 0.0), 1.0), sent)
        self.delay = max(self.delay, delay)

    def heard_pace(self, now: float) -> float:
        """The slowest pace heard that is still fresh (1 without one)."""
        fresh = self.params.fresh_s
        return min((p for _d, p, t in self._heard.values() if now - t < fresh), default=1.0)

    def behind(self, now: float) -> float:
        """How far the plan's time stands behind `now - t0` (s): the delay, carried forward at each
        fresh pace below 1 heard, but never so far that the plan's time goes back from the last
        one given."""
        fresh, out = self.params.fresh_s, self.delay
        for d, p, t in self._heard.values():
            if p < 1.0 and now - t < fresh:
                out = max(out, d + (1.0 - p) * max(now - t, 0.0))
        if self._given is not None:
            out = min(out, self._given[1] + max(now - self._given[0], 0.0))
        self._given = (now, out)
        return out

    def wait(self, now: float, pace: float) -> float:
        """This executor's vehicles let the clock run at `pace` since the last call (at most
        `max_step_s` of it): the delay grows by what they held it back (on top of the largest
        heard); the delay now."""
        self.waited = 0.0
        if self._last is not None and self.params.enabled:
            dt, step = max(now - self._last, 0.0), self.params.max_step_s
            self.waited = (1.0 - min(max(pace, 0.0), 1.0)) * min(dt, step) + max(dt - step, 0.0)
            self.delay += self.waited
        self._last = now
        return self.delay
