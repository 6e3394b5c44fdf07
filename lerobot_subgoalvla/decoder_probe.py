"""One line instead of LeRobot's 60-line torchcodec report when FFmpeg's shared libraries are missing.

LeRobot's default video decoder is torchcodec. When torchcodec is installed but cannot load FFmpeg's shared
libraries (a machine without them), ``lerobot.utils.import_utils.get_safe_default_video_backend`` logs the
whole loader error (every FFmpeg version tried, with its traceback: about 60 lines) before every
``lerobot-train`` run, and then decodes with PyAV anyway. The plugin is imported before LeRobot parses its
config, so a logging filter on that logger turns the report into one warning that says what it means and how
to fix it. Nothing else LeRobot logs is touched.
"""

from __future__ import annotations

import logging

#: The logger ``get_safe_default_video_backend`` writes to.
LEROBOT_IMPORT_LOGGER = "lerobot.utils.import_utils"
#: A fragment of LeRobot 0.6's message for a torchcodec that is installed but cannot load.
_CANNOT_LOAD = "'torchcodec' is installed but cannot be loaded"
ONE_LINE = (
    "torchcodec cannot load FFmpeg's shared libraries (FFmpeg 4-7), so LeRobot decodes videos with PyAV; "
    "for faster decoding install them (Debian 12: apt-get install libavutil57 libavcodec59 libavformat59 "
    "libavdevice59 libavfilter8 libswscale6 libswresample4), or pass --dataset.video_backend=pyav"
)


class TorchcodecReportFilter(logging.Filter):
    """Replaces LeRobot's torchcodec loader report with :data:`ONE_LINE`; passes every other record."""

    def filter(self, record: logging.LogRecord) -> bool:
        if _CANNOT_LOAD in str(record.msg):
            record.msg, record.args = ONE_LINE, None
        return True


def install() -> None:
    """Add the filter to LeRobot's import logger (once)."""
    target = logging.getLogger(LEROBOT_IMPORT_LOGGER)
    if not any(isinstance(f, TorchcodecReportFilter) for f in target.filters):
        target.addFilter(TorchcodecReportFilter())
