"""Events in one in-memory form (a structured numpy array plus the sensor size), file readers
and writers, and binning into TOFFE's discretized event volume."""
from .core import EVENT_DTYPE, Events, make_events
from .binning import bin_window, window_slice
from .io import EventSource, detect_format, open_events, read_events, write_events_h5, write_events_npz

__all__ = ["EVENT_DTYPE", "Events", "make_events", "bin_window", "window_slice", "EventSource",
           "detect_format", "open_events", "read_events", "write_events_h5", "write_events_npz"]
