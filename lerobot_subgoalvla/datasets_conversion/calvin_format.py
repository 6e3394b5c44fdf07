"""CALVIN's native dataset format: schema, reader and writer (docs/calvin.md section 1).

A CALVIN split directory (``training/`` or ``validation/``) holds one ``episode_XXXXXXX.npz`` per 30 Hz
frame (7-digit, zero-padded frame id), the segment table ``ep_start_end_ids.npy`` (inclusive rows;
windows never cross rows), ``ep_lens.npy``, ``scene_info.npy`` (training only), ``statistics.yaml``
and ``lang_annotations/auto_lang_ann.npy``. :class:`CalvinSplit` reads that layout; the ``write_*``
functions produce it (for the generator and for tests) with atomic renames, so an interrupted writer
never leaves a truncated file under a final name. Validation lives in ``calvin_validate.py``, the
dataset quirks (slot order, window clamping) in ``calvin_quirks.py``.

Dimension legend:
    N    segments (rows of ep_start_end_ids) or language windows
    F    frames in a range
    D    language embedding dimension (384 for CALVIN's MiniLM)
"""

from __future__ import annotations

import pickle
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from zlib import error as zlib_error

import numpy as np
import yaml

from lerobot_subgoalvla.atomic_files import atomic_write
from lerobot_subgoalvla.calvin_vocab import check_task_name

SPLITS: tuple[str, ...] = ("training", "validation")
EPISODE_IDS_FILE = "ep_start_end_ids.npy"
EPISODE_LENS_FILE = "ep_lens.npy"
SCENE_INFO_FILE = "scene_info.npy"
STATISTICS_FILE = "statistics.yaml"
LANG_ANN_FILE = Path("lang_annotations") / "auto_lang_ann.npy"
#: The validation split of every CALVIN release is scene D (spec 1.1); it has no scene_info.npy.
VALIDATION_SCENE = "calvin_scene_D"


@dataclass(frozen=True)
class ArraySpec:
    """Expected on-disk dtype kind and shape of one npz key (spec 1.3).

    ``kind`` is a numpy dtype kind: ``"f"`` (CALVIN writes float64 for the vectors although its README says
    float32, so any float width is accepted) or ``"u"`` (uint8 images). Image heights/widths are read from
    the data (``shape=None`` entries per axis) so that generated datasets may use smaller cameras.
    """

    kind: str
    itemsize: int | None
    shape: tuple[int | None, ...]

    def matches(self, array: np.ndarray) -> bool:
        """Whether ``array`` has this kind, item size (if fixed) and shape (None axes are free)."""
        if array.dtype.kind != self.kind or (
            self.itemsize is not None and array.dtype.itemsize != self.itemsize
        ):
            return False
        if array.ndim != len(self.shape):
            return False
        return all(want is None or want == got for want, got in zip(self.shape, array.shape, strict=True))

    def describe(self) -> str:
        """Human-readable form, e.g. ``uint8 (H, W, 3)``."""
        dtype = {"f": "float", "u": "uint"}[self.kind] + (str(self.itemsize * 8) if self.itemsize else "")
        axes = ", ".join("any" if axis is None else str(axis) for axis in self.shape)
        return f"{dtype} ({axes})"


#: The 10 keys of every native frame file (spec 1.3).
NPZ_SCHEMA: Mapping[str, ArraySpec] = {
    "actions": ArraySpec("f", None, (7,)),
    "rel_actions": ArraySpec("f", None, (7,)),
    "robot_obs": ArraySpec("f", None, (15,)),
    "scene_obs": ArraySpec("f", None, (24,)),
    "rgb_static": ArraySpec("u", 1, (None, None, 3)),
    "rgb_gripper": ArraySpec("u", 1, (None, None, 3)),
    "rgb_tactile": ArraySpec("u", 1, (160, 120, 6)),
    "depth_static": ArraySpec("f", None, (None, None)),
    "depth_gripper": ArraySpec("f", None, (None, None)),
    "depth_tactile": ArraySpec("f", None, (160, 120, 2)),
}
#: The keys the converter reads; the generator writes exactly these (it renders no depth/tactile sensors).
CORE_KEYS: tuple[str, ...] = ("actions", "rel_actions", "robot_obs", "scene_obs", "rgb_static", "rgb_gripper")
ALL_KEYS: tuple[str, ...] = tuple(NPZ_SCHEMA)


def frame_filename(frame_id: int) -> str:
    """``episode_XXXXXXX.npz`` with the 7-digit zero-padded frame id (spec 1.1)."""
    return f"episode_{int(frame_id):07d}.npz"


@dataclass
class LanguageAnnotations:
    """``auto_lang_ann.npy`` (spec 1.7): one row per annotated window.

    Attributes:
        indx: (N, 2) int64 ``(start_id, end_id)``; ``end`` is inclusive (CALVIN's loaders treat it so).
        ann: N instruction strings.
        task: N task names (one of the 34).
        emb: (N, 1, D) float32 sentence embeddings, or None when the file has none (generated data).
    """

    indx: np.ndarray
    ann: list[str]
    task: list[str]
    emb: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.indx = np.asarray(self.indx, dtype=np.int64).reshape(-1, 2)  # (N, 2)
        if not len(self.ann) == len(self.task) == len(self.indx):
            raise ValueError(
                f"language annotations disagree in length: {len(self.indx)} windows, {len(self.ann)} ann, "
                f"{len(self.task)} task; rewrite auto_lang_ann.npy with one ann and task per window"
            )

    def __len__(self) -> int:
        return len(self.indx)

    def to_dict(self) -> dict:
        """CALVIN's nested dict layout (``info.indx``, ``info.episodes``, ``language.ann/task/emb``)."""
        language: dict = {"ann": list(self.ann), "task": list(self.task)}
        if self.emb is not None:
            language["emb"] = np.asarray(self.emb, dtype=np.float32)
        return {
            "info": {"indx": [tuple(int(v) for v in row) for row in self.indx], "episodes": []},
            "language": language,
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> LanguageAnnotations:
        """Parse CALVIN's nested dict; raises KeyError naming a missing key."""
        language = data["language"]
        emb = language.get("emb")
        indx = np.asarray(data["info"]["indx"], dtype=np.int64).reshape(-1, 2)  # (N, 2)
        ann = [_text(a, "instruction", i) for i, a in enumerate(language["ann"])]
        task = [check_task_name(_text(t, "task name", i)) for i, t in enumerate(language["task"])]
        return cls(indx=indx, ann=ann, task=task, emb=emb)


def _text(value: object, what: str, index: int) -> str:
    """A non-empty str from a str or UTF-8 bytes; ValueError naming the window otherwise."""
    if isinstance(value, bytes | np.bytes_):
        try:
            value = bytes(value).decode("utf-8")
        except UnicodeDecodeError as error:
            raise ValueError(f"window {index}: {what} {bytes(value)!r} is not UTF-8 ({error})") from None
    if not isinstance(value, str | np.str_) or not str(value).strip():
        raise ValueError(f"window {index}: empty or non-text {what} {value!r}")
    try:
        str(value).encode("utf-8")
    except UnicodeEncodeError as error:  # a lone surrogate: no file format or tokenizer can store it
        raise ValueError(f"window {index}: {what} {value!r} is not valid Unicode ({error.reason})") from None
    return str(value)


def check_frame(path: Path, keys: Sequence[str] = CORE_KEYS) -> dict[str, np.ndarray]:
    """Load ``keys`` of one frame file and check them against :data:`NPZ_SCHEMA`.

    Raises:
        FileNotFoundError: the file is missing.
        ValueError: the file is corrupt, lacks a key, a key has the wrong shape/dtype, or a float key holds a
            NaN or an infinity. One line naming the file and the fix.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: frame file missing although ep_start_end_ids.npy covers it; restore the file or fix "
            "the segment table"
        )
    try:
        with zipfile.ZipFile(path) as archive:  # an npz is a zip of .npy members
            members = {name.removesuffix(".npy") for name in archive.namelist()}
        missing = [key for key in keys if key not in members]
        if not missing:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {key: npz[key] for key in keys}
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, zlib_error) as error:
        raise ValueError(
            f"{path}: corrupt npz ({error}); re-download or regenerate this frame file"
        ) from error
    if missing:
        raise ValueError(
            f"{path}: missing key(s) {missing} (has {sorted(members)}); re-export the frame with all keys "
            f"{list(keys)}"
        )
    for key, array in arrays.items():
        spec = NPZ_SCHEMA[key]
        if not spec.matches(array):
            raise ValueError(
                f"{path}: key {key!r} is {array.dtype} {array.shape}, expected {spec.describe()}; "
                "re-export the frame in CALVIN's format (docs/calvin.md 1.3)"
            )
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            bad = np.flatnonzero(~np.isfinite(array.ravel()))
            raise ValueError(
                f"{path}: key {key!r} holds {array.ravel()[bad[0]]} at index {int(bad[0])} ({len(bad)} "
                "non-finite value(s)); fix or drop this frame: statistics and training would turn NaN"
            )
    return arrays


def _load_pickled(path: Path) -> object:
    try:
        return np.load(path, allow_pickle=True).item()
    except (pickle.UnpicklingError, EOFError, OSError, ValueError, AttributeError) as error:
        raise ValueError(
            f"{path}: unreadable ({type(error).__name__}: {error}); re-download this file"
        ) from None


@dataclass
class CalvinSplit:
    """Read access to one native split directory.

    Args:
        root: the split directory (``.../training`` or ``.../validation``).

    Attributes:
        segments: (N, 2) int64 inclusive ``[start_id, end_id]`` rows of ``ep_start_end_ids.npy``.
        scene_info: ``{scene_name: (first_id, last_id)}`` (inclusive) or the validation default.
    """

    root: Path
    segments: np.ndarray = field(init=False)
    scene_info: dict[str, tuple[int, int]] = field(init=False)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        self.segments = np.asarray(np.load(self.root / EPISODE_IDS_FILE), dtype=np.int64).reshape(
            -1, 2
        )  # (N, 2)
        scene_path = self.root / SCENE_INFO_FILE
        if scene_path.is_file():
            raw = _load_pickled(scene_path)
            self.scene_info = {str(k): (int(v[0]), int(v[1])) for k, v in dict(raw).items()}
        else:
            covered = (
                (int(self.segments[:, 0].min()), int(self.segments[:, 1].max()))
                if len(self.segments)
                else (0, -1)
            )
            self.scene_info = {VALIDATION_SCENE: covered}

    @property
    def name(self) -> str:
        """``training`` or ``validation`` (the directory name)."""
        return self.root.name

    @property
    def num_frames(self) -> int:
        """Frames covered by the segment table (stray files outside any row are not counted)."""
        return int((self.segments[:, 1] - self.segments[:, 0] + 1).sum())

    def frame_path(self, frame_id: int) -> Path:
        """Path of the npz file of ``frame_id``."""
        return self.root / frame_filename(frame_id)

    def scene_of(self, frame_id: int) -> str:
        """Scene name of a frame from ``scene_info`` (inclusive ranges)."""
        for scene, (first, last) in self.scene_info.items():
            if first <= frame_id <= last:
                return scene
        raise ValueError(
            f"{self.root / SCENE_INFO_FILE}: frame {frame_id} lies in no scene range {self.scene_info}; "
            "fix scene_info.npy so its inclusive ranges cover every segment"
        )

    def language(self) -> LanguageAnnotations:
        """Parse ``lang_annotations/auto_lang_ann.npy`` (raises FileNotFoundError when absent)."""
        path = self.root / LANG_ANN_FILE
        if not path.is_file():
            raise FileNotFoundError(
                f"{path}: language annotations not found; LANG mode needs them - use --mode all or add the "
                "file"
            )
        try:
            return LanguageAnnotations.from_dict(_load_pickled(path))
        except KeyError as error:
            raise ValueError(f"{path}: no {error} entry; not CALVIN's auto_lang_ann layout") from None
        except ValueError as error:
            message = str(error)
            raise ValueError(message if message.startswith(str(path)) else f"{path}: {message}") from None

    def statistics(self) -> dict | None:
        """``statistics.yaml`` as a dict, or None when the split has none."""
        path = self.root / STATISTICS_FILE
        return yaml.safe_load(path.read_text()) if path.is_file() else None

    def load_frames(self, frame_ids: Iterable[int], keys: Sequence[str] = CORE_KEYS) -> dict[str, np.ndarray]:
        """Stack ``keys`` of the given frames (only those keys are decompressed).

        Returns:
            ``{key: (F, ...) array}`` in the files' own dtypes.
        """
        ids = list(frame_ids)
        frames = [check_frame(self.frame_path(i), keys) for i in ids]
        for key in keys:
            for frame_id, frame in zip(ids[1:], frames[1:], strict=True):
                if frame[key].shape != frames[0][key].shape:
                    raise ValueError(
                        f"{self.frame_path(frame_id)}: {key!r} is {frame[key].shape} but "
                        f"{self.frame_path(ids[0]).name} has {frames[0][key].shape}; every frame of a split "
                        "needs the same image sizes (re-export it, or convert the splits separately)"
                    )
        return {key: np.stack([frame[key] for frame in frames]) for key in keys}  # (F, ...)


# --------------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------------


def write_frame(split_dir: Path, frame_id: int, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write one ``episode_XXXXXXX.npz`` (np.savez_compressed, atomic). Returns its path."""
    path = Path(split_dir) / frame_filename(frame_id)
    for key, value in arrays.items():
        value = np.asarray(value)
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            raise ValueError(f"{path}: refusing to write non-finite values in key {key!r}")
    atomic_write(
        path, lambda handle: np.savez_compressed(handle, **{k: np.asarray(v) for k, v in arrays.items()})
    )
    return path


def write_npy(path: Path, value: object) -> None:
    """``np.save`` atomically (pickled dicts via ``allow_pickle``, as CALVIN stores them)."""
    atomic_write(Path(path), lambda handle: np.save(handle, value, allow_pickle=True))


def write_segments(split_dir: Path, segments: np.ndarray) -> None:
    """``ep_start_end_ids.npy`` (N, 2) inclusive rows and the matching ``ep_lens.npy`` (N,)."""
    segments = np.asarray(segments, dtype=np.int64).reshape(-1, 2)  # (N, 2)
    write_npy(Path(split_dir) / EPISODE_IDS_FILE, segments)
    write_npy(Path(split_dir) / EPISODE_LENS_FILE, segments[:, 1] - segments[:, 0] + 1)


def write_scene_info(split_dir: Path, scene_info: Mapping[str, tuple[int, int]]) -> None:
    """``scene_info.npy``: pickled ``{scene_name: [first_id, last_id]}`` (inclusive; training only)."""
    write_npy(
        Path(split_dir) / SCENE_INFO_FILE,
        np.array({k: [int(v[0]), int(v[1])] for k, v in scene_info.items()}),
    )


def write_language(split_dir: Path, annotations: LanguageAnnotations) -> None:
    """``lang_annotations/auto_lang_ann.npy`` in CALVIN's nested dict layout."""
    write_npy(Path(split_dir) / LANG_ANN_FILE, np.array(annotations.to_dict()))


def compute_statistics(robot_obs: np.ndarray, scene_obs: np.ndarray, actions: np.ndarray) -> dict:
    """CALVIN's ``statistics.yaml`` content (spec 1.2) from (F, 15), (F, 24) and absolute (F, 7) actions."""

    def normalizer(values: np.ndarray) -> list[dict]:
        return [
            {
                "_target_": "calvin_agent.utils.transforms.NormalizeVector",
                "mean": [float(v) for v in values.mean(axis=0)],
                "std": [float(v) for v in values.std(axis=0)],
            }
        ]

    return {
        "robot_obs": normalizer(robot_obs),
        "scene_obs": normalizer(scene_obs),
        "act_min_bound": [float(v) for v in actions.min(axis=0)],
        "act_max_bound": [float(v) for v in actions.max(axis=0)],
    }


def write_statistics(split_dir: Path, statistics: Mapping) -> None:
    """``statistics.yaml`` (atomic)."""
    text = yaml.safe_dump(dict(statistics), sort_keys=False).encode()
    atomic_write(Path(split_dir) / STATISTICS_FILE, lambda handle: handle.write(text))
