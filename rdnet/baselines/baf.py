"""Background-activity filter (BAF) of Delbruck ("Frame-free dynamic digital vision",
2008), as implemented by jAER's ``BackgroundActivityFilter`` and v2e's
``BackgroundActivityFilter``: an event is kept when at least one of its 8 neighbouring
pixels fired within the last ``dt_us`` before it; the pixel itself does not count
(``include_self=False``, the jAER/v2e behaviour), so a hot pixel firing on its own, or an
isolated noise event, is removed. Those implementations write each event's time into
its neighbours' cells of a timestamp map and test the event's own cell; that is the
same rule as reading the neighbours' last times, i.e. :func:`rdnet.baselines.stcf.stcf_mask`
with ``k=1``, ``radius=1``, both polarities together -- which is what this module calls.
(jAER compares with ``<`` or ``<=`` depending on version; here ``t - t_neighbour <= dt_us``.)

Streaming: pass one :class:`~rdnet.baselines.stcf.StcfState` (:func:`baf_state`) to
successive calls on consecutive chunks; the result equals one call on the whole stream.
"""
from __future__ import annotations

import numpy as np

from rdnet.baselines.stcf import StcfState, stcf_mask
from rdnet.events.core import Events


def baf_state(width: int, height: int) -> StcfState:
    """An empty timestamp map for streaming :func:`baf_mask` over a ``width`` x ``height`` sensor."""
    return StcfState(width, height, same_polarity=False)


def baf_mask(events: Events, dt_us: int = 10000, *, include_self: bool = False,
             state: StcfState | None = None) -> np.ndarray:
    """Boolean keep-mask: a neighbour (8-connected) fired within ``dt_us`` before the event."""
    return stcf_mask(events, dt_us, k=1, radius=1, include_self=include_self,
                     same_polarity=False, state=state)


def baf_filter(events: Events, dt_us: int = 10000, *, include_self: bool = False,
               state: StcfState | None = None) -> Events:
    """The events :func:`baf_mask` keeps."""
    return events.select(baf_mask(events, dt_us, include_self=include_self, state=state))
