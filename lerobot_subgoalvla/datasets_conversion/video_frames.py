"""Videos that keep every recorded frame: LeRobot's streaming encoder without dropped frames, and the check.

Why: LeRobot's streaming encoder (``streaming_encoding=True``) hands frames to a background encoder thread
through a bounded queue and, when the queue stays full for 0.1 s, *drops* the frame with nothing but a log
warning: it is built for live recording, where blocking would stall the robot. Written from files, frames
arrive faster than SVT-AV1 encodes them, so the queue is full all the time and any stall of the encoder
thread (a busy machine) loses frames. The video then holds fewer frames than the parquet has rows, every later
frame of that file is served for the wrong timestamp (within LeRobot's tolerance, so silently), and training
stops only at the file's last frame with ``FrameTimestampError`` (CI, the learning guard: 3,125 frames encoded
of 3,126). A queue that can hold a whole episode never fills, so nothing is dropped whatever the load; its
memory is at most one episode's frames per camera, so episodes longer than :data:`MAX_STREAMED_FRAMES` are
encoded by LeRobot's batch path instead (frames as PNG files, encoded at ``save_episode``).

:func:`check_video_frames` counts the frames of every video file (demuxed packets, nothing decoded: well under
a second per file) against the episodes LeRobot recorded in it; the writers call it on each dataset they
finish, so a dataset with a missing frame is never renamed into place.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

#: Longest episode streamed to the encoder (a full queue of CALVIN's two cameras is about 290 MB per writer).
MAX_STREAMED_FRAMES = 2048


def encoder_options(use_videos: bool, longest_episode: int) -> dict:
    """``LeRobotDataset.create`` keywords that encode while recording without ever dropping a frame.

    Args:
        use_videos: whether the dataset stores its cameras as videos (nothing to encode otherwise).
        longest_episode: frames of the longest episode that will be written into the dataset.
    """
    if not use_videos or longest_episode > MAX_STREAMED_FRAMES:
        return {"streaming_encoding": False}
    # One more slot than frames: ``put`` never waits, so its 0.1 s timeout (the drop) can never fire.
    return {"streaming_encoding": True, "encoder_queue_maxsize": longest_episode + 1}


def count_video_frames(path: Path) -> int:
    """Frames in the first video stream of ``path``, counted from its packets (no decoding)."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return sum(1 for packet in container.demux(stream) if packet.size)


def check_video_frames(root: Path) -> int:
    """Check that each video file of the LeRobotDataset at ``root`` holds every frame of its episodes.

    Returns:
        The number of video files checked.

    Raises:
        ValueError: one line naming the file, the frame counts and the fix.
    """
    from lerobot.datasets import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(repo_id=f"local/{root.name}", root=root)
    columns = [f"videos/{key}/{index}" for key in meta.video_keys for index in ("chunk_index", "file_index")]
    expected: dict[str, int] = defaultdict(int)
    for episode in meta.episodes.select_columns(["length", *columns]):
        for key in meta.video_keys:
            chunk, file = episode[f"videos/{key}/chunk_index"], episode[f"videos/{key}/file_index"]
            path = meta.video_path.format(video_key=key, chunk_index=chunk, file_index=file)
            expected[path] += episode["length"]
    for relative, frames in expected.items():
        encoded = count_video_frames(root / relative)
        if encoded != frames:
            raise ValueError(
                f"{root / relative}: {encoded} frames encoded for {frames} recorded ones (the video encoder "
                "dropped or added frames); delete this output and write it again"
            )
    return len(expected)
