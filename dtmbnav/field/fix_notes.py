"""What the user is told about a phone log's fixes without C/N0, said once a log by either reader.

A fix's C/N0 grades it where the fusion takes fixes as observations (:class:`fusion.adaptive_kf.GnssFixes`);
a fix without one is weighted by its stated horizontal accuracy instead, as the start fix always is
(:func:`dtmbnav.field.sensors_import.choose_start_fix`). Sensor Logger logs no C/N0; GnssLogger's fixes
lack it where no Status report of their satellites lies near them.
"""

from __future__ import annotations

import numpy as np

from dtmbnav_core.phone import ACCURACY_RADIUS_SIGMAS


def missing_cn0(source: str, cn0_dbhz: np.ndarray, why: str = "") -> list[str]:
    """The note for the fixes of ``source`` whose C/N0 (dB-Hz) is NaN, ``why`` (e.g. ``" (no Status report
    ...)"``) said after their count; none where every fix has one."""
    missing = int(np.isnan(cn0_dbhz).sum())
    if not missing:
        return []
    note = (f"{source}: {missing} of {len(cn0_dbhz)} fixes have no C/N0{why}: weighted by their stated accuracy "
            f"(per-axis sigma = accuracy / {ACCURACY_RADIUS_SIGMAS:.2f})")
    return [note]
