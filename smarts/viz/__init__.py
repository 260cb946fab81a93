"""The diagnostic web viewer: live and recorded episodes in a browser (``smarts viz``).

``WatchedEnv`` records a ``DrivingParallelEnv``'s episodes (``smarts.viz.recording``) and/or
streams them to a running viewer; ``smarts.viz.server`` serves the page, recordings and benchmark
episode logs. Nothing below this package imports it.
"""

from smarts.viz.recording import Recording, read_recording, write_recording
from smarts.viz.watch import WatchedEnv

__all__ = ["Recording", "WatchedEnv", "read_recording", "write_recording"]
