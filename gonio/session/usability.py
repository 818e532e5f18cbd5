"""Whether a session's poses give anything usable, and what a session that cannot succeed says.

A pose can be measured without error and still give nothing a fit or a calibration can use: every sample
flagged (the ChArUco board never found — NO_BOARD, the camera pose then from the kinematics only —,
saturated, too little signal), no sample at all, skipped (board or sample not in the image, unreachable), or,
in a calibration session, no board pose or no highlight (off the tile, cut by its edge, saturated). A run
counts such poses per cause (:class:`Usability`; a resumed session goes on from its last run's counts, so a
session is judged whole):

* it **stops** once at least :data:`STOP_AFTER` poses were tried in this run and at least
  :data:`STOP_FRACTION` of them were unusable (a board out of view, a camera file of another camera, a
  tile missing: nothing the next poses will change);
* it **ends** ``unusable: ...`` (never ``completed``; ``gonio measure`` exits :data:`UNUSABLE_EXIT`) when more
  than :data:`UNUSABLE_FRACTION` of the poses tried in the run (at least :data:`MIN_JUDGED`) were unusable,
  naming the causes;
* it **warns** (one line, with the causes) when more than :data:`WARN_FRACTION` were.

The status line names the poses and the causes counted, most frequent first, e.g. ``unusable: 12 of 12 poses
tried gave nothing usable (board not found (every sample NO_BOARD): 12)``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Usability", "sample_cause", "run_warning", "outcome_lines", "UNUSABLE_EXIT", "STOP_AFTER", "STOP_FRACTION", "UNUSABLE_FRACTION",
           "WARN_FRACTION", "STATUS_PREFIX", "MIN_JUDGED"]

#: Exit status of a session (or calibration) that ended ``unusable``.
UNUSABLE_EXIT = 8
#: The manifest's exit status of such a session starts with this.
STATUS_PREFIX = "unusable"
#: Poses tried in a run before it may stop for unusable poses.
STOP_AFTER = 10
#: Fraction of the poses tried at which a run stops (after :data:`STOP_AFTER`).
STOP_FRACTION = 0.9
#: Fraction of unusable poses above which a finished run ends ``unusable``.
UNUSABLE_FRACTION = 0.5
#: Poses a finished run must have tried to be judged (a resume that measured one grazing pose is not a session).
MIN_JUDGED = 3
#: Fraction above which a finished run warns, naming the causes.
WARN_FRACTION = 0.2

#: What each sample flag means as the cause of a pose none of whose samples is usable.
_FLAG_CAUSES = {
    "no_board": "board not found (every sample NO_BOARD)",
    "saturated": "saturated",
    "low_signal": "too little signal",
    "bad_frame": "bad frames",
    "shadowed": "shadowed",
    "drift": "light drift",
}


def sample_cause(samples) -> str | None:
    """Why a pose's samples are unusable (``None``: at least one sample has no flag): no samples at all, or the
    flag most samples carry (:data:`gonio.samples.FLAG_NAMES`)."""
    from gonio.samples import FLAG_NAMES

    if samples is None or len(samples) == 0:
        return "no samples (sample or white patch outside the image)"
    flags = np.asarray(samples.flags)
    if np.any(flags == 0):
        return None
    counts = {name: int(np.count_nonzero(flags & bit)) for bit, name in FLAG_NAMES.items()}
    name = max(counts, key=counts.get)
    return _FLAG_CAUSES.get(name, name)


@dataclass
class Usability:
    """Counts of a run's tried poses and of its unusable ones by cause (module docstring)."""

    tried: int = 0
    causes: Counter = field(default_factory=Counter)

    @property
    def unusable(self) -> int:
        return sum(self.causes.values())

    def add(self, cause: str | None) -> None:
        """One pose tried: ``cause`` why it is unusable, ``None`` if it is usable."""
        self.tried += 1
        if cause:
            self.causes[_short(cause)] += 1

    def _what(self) -> str:
        return "; ".join(f"{c}: {n}" for c, n in self.causes.most_common())

    def should_stop(self) -> str | None:
        """The status to stop with now (``None``: go on)."""
        if self.tried >= STOP_AFTER and self.unusable >= STOP_FRACTION * self.tried:
            return (f"{STATUS_PREFIX}: stopped after {self.tried} poses, {self.unusable} of them gave nothing usable "
                    f"({self._what()})")
        return None

    def final_status(self) -> str | None:
        """The status a finished run ends with instead of ``completed`` (``None``: it may say completed)."""
        if self.tried >= MIN_JUDGED and self.unusable > UNUSABLE_FRACTION * self.tried:
            return f"{STATUS_PREFIX}: {self.unusable} of {self.tried} poses tried gave nothing usable ({self._what()})"
        return None

    def warning(self) -> str | None:
        """One line when more than :data:`WARN_FRACTION` of the poses were lost (with the causes)."""
        if self.tried and self.unusable > WARN_FRACTION * self.tried:
            return (f"warning: {self.unusable} of {self.tried} poses ({100 * self.unusable / self.tried:.0f} %) gave "
                    f"nothing usable: {self._what()}")
        return None

    def to_dict(self) -> dict:
        """What :attr:`gonio.session.runner.RunResult.usability` (and the manifest's ``last_run``) holds."""
        return {"tried": self.tried, "unusable": self.unusable, "causes": dict(self.causes.most_common())}

    @classmethod
    def from_dict(cls, d) -> "Usability":
        """Inverse of :meth:`to_dict` (an empty dict: nothing tried)."""
        d = d if isinstance(d, dict) else {}
        try:  # a manifest's (untrusted) counts: anything malformed counts as nothing
            return cls(int(d.get("tried", 0)), Counter({str(k): int(v) for k, v in dict(d.get("causes", {})).items()}))
        except (TypeError, ValueError):
            return cls()


def run_warning(result) -> str | None:
    """The warning line of a run (:class:`gonio.session.runner.RunResult`) that lost more than
    :data:`WARN_FRACTION` of its poses and did not end ``unusable`` (that status names the causes itself)."""
    if str(result.status).startswith(STATUS_PREFIX):
        return None
    return Usability.from_dict(getattr(result, "usability", None)).warning()


#: Causes as counted: the first pattern found in a reason (lower case) names its cause.
_KINDS = (("board not found", "board not found"), ("outside the image", "sample or board outside the image"),
          ("tile's edge", "highlight too near the tile's edge"), ("frame's edge", "highlight at the frame's edge"),
          ("saturated", "saturated"), ("no highlight", "no highlight (too faint)"),
          ("two bright spots", "two bright spots"), ("larger than", "highlight too large (out of focus?)"),
          ("unreachable", "unreachable"), ("collision", "unreachable"), ("limit", "unreachable"))


def _short(cause: str) -> str:
    """A cause as counted: its kind (:data:`_KINDS`), else its text with the numbers that vary per pose left out."""
    import re

    c = str(cause).strip()
    low = c.lower()
    if c in _FLAG_CAUSES.values():
        return c
    for pattern, kind in _KINDS:
        if pattern in low:
            return kind
    return re.sub(r"\s+", " ", re.sub(r"\([^)]*\)|[-+]?\d[\d.eE+-]*", "", c)).strip(" :;,")[:80]


def outcome_lines(result) -> list[str]:
    """What ``gonio measure``/``resume`` say of a session's usability (:class:`gonio.session.api.SessionResult`):
    the warning of a run that lost many poses, or why an ``unusable`` one is, and what to do."""
    out = []
    warn = run_warning(result.run) if result.run is not None else None
    if warn:
        out.append(f"gonio: {warn}")
    if str(result.status).startswith(STATUS_PREFIX):
        out.append(f"gonio: session {result.status}; nothing here to fit: fix the cause (is the board in view and "
                   f"lit, the camera file this camera's, the exposure range right?) and start a new session "
                   f"(`gonio status {result.directory}` shows the run)")
    return out

