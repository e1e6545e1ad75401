"""Alert, exclusion, availability and fault-onset events of a run, from its monitor outputs block by block.

Shared by the flight loop and ``testbed monitor`` (a recorded file): the same
texts go to the Rerun text log and the same marks onto the integrity plots.
"""

from __future__ import annotations

from testbed.integrity.fde import measurement_label

INFO, WARN, ERROR = "INFO", "WARN", "ERROR"


class EventTracker:
    """Remembers each monitor's last alert / exclusion / availability so changes become events.

    onsets : (t, kind) of injected faults (truth side; empty for a recorded file).
    """

    def __init__(self, monitors, onsets=()) -> None:
        self.prev_alert = {m: False for m in monitors}
        self.prev_avail = {m: True for m in monitors}
        self.prev_excluded = {m: -1 for m in monitors}
        self.onsets = list(onsets)
        self.onset_logged: set = set()

    def add(self, block) -> list[tuple[float, str, str]]:
        """Append ``block``'s events and marks to it (and return the events, in time order)."""
        t_end = float(block.t[-1]) if block.t.size else -1.0
        for onset, kind in self.onsets:
            if onset <= t_end and (onset, kind) not in self.onset_logged:
                self.onset_logged.add((onset, kind))
                block.events.append((onset, WARN, f"[truth] fault injected: {kind} at t = {onset:.1f} s"))
                block.marks.append((onset, "", "fault onset"))
        for name, out in block.outputs.items():
            level0 = out.service_levels[0] if out.service_levels else "?"
            for i, t in enumerate(out.t):
                a = bool(out.alert[i])
                if a and not self.prev_alert[name]:
                    block.events.append((float(t), ERROR, f"{name}: ALERT test statistic {out.test_stat[i]:.1f} "
                                                           f"> threshold {out.threshold[i]:.1f}"))
                    block.marks.append((float(t), name, "alert"))
                elif not a and self.prev_alert[name]:
                    block.events.append((float(t), INFO, f"{name}: alert cleared"))
                    block.marks.append((float(t), name, "alert cleared"))
                self.prev_alert[name] = a
                ex = int(out.excluded[i])
                if ex >= 0 and ex != self.prev_excluded.get(name, -1):
                    what = measurement_label(ex, block.gnss.prn, None if block.vision is None else block.vision.landmark_id,
                                             block.gnss.system)
                    block.events.append((float(t), WARN, f"{name}: fault detected, {what} EXCLUDED (test "
                                                          f"{out.fde.test_stat_all[i]:.1f} > {out.fde.threshold_all[i]:.1f}; "
                                                          f"without it {out.test_stat[i]:.1f} ≤ {out.threshold[i]:.1f})"))
                    block.marks.append((float(t), name, "excluded"))
                elif ex < 0 and self.prev_excluded.get(name, -1) >= 0:
                    block.events.append((float(t), INFO, f"{name}: exclusion ended"))
                self.prev_excluded[name] = ex
                av = bool(out.available[i, 0]) if out.available.ndim == 2 and out.available.shape[1] else True
                if av != self.prev_avail[name]:
                    why = out.reasons[out.reason[i]] if out.reason[i] else "PL above alert limit"
                    block.events.append((float(t), WARN if not av else INFO,
                                         f"{name}: {level0} {'available' if av else 'UNAVAILABLE (' + why + ')'}"))
                    block.marks.append((float(t), name, "available" if av else "unavailable"))
                self.prev_avail[name] = av
        block.events.sort(key=lambda e: e[0])
        return block.events
