"""A detector's boxes for one image, and readers of the files detectors write.

:class:`ImageDetections` is what the front-end takes from any detector: per image, axis-aligned
boxes in the left (and optionally right) raw image in pixels, a class label, a score in
``[0, 1]`` and optionally an embedding vector per box (a re-identification network's output).
Boxes carry no object id: which object a box shows is decided by the tracker and the
association.

:func:`read_detections` reads a folder of YOLO text files (as ultralytics writes them) or a COCO
results JSON into one :class:`ImageDetections` per image, in the caller's image order. Boxes come
out in the OpenCV pixel-centre convention (the top-left pixel's centre is ``(0, 0)``, so the
whole image spans ``[-0.5, W - 0.5] × [-0.5, H - 0.5]``), clipped to the image; boxes wholly
outside are dropped, and both are counted. Every malformed input raises
:class:`~teamslam.errors.InputError` naming the file and the line (YOLO) or entry (COCO). The
formats are described on the guide page *Detections*.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from teamslam.errors import InputError

__all__ = ["DetectionsRead", "ImageDetections", "clip_boxes", "read_detections"]


@dataclass(frozen=True)
class ImageDetections:
    """The boxes a detector found in one image.

    Attributes
    ----------
    boxes
        ``(M, 4)`` float64 ``(x_min, y_min, x_max, y_max)`` in pixels of the raw image
        (OpenCV convention: the top-left pixel's centre is ``(0, 0)``), inside the image.
    classes
        ``(M,)`` int64 class labels ``≥ 0``.
    scores
        ``(M,)`` float64 scores in ``[0, 1]`` (``1`` when the detector wrote none).
    embeddings
        ``(M, D)`` float32 per-box embedding vectors, or ``None``.
    """

    boxes: np.ndarray
    classes: np.ndarray
    scores: np.ndarray
    embeddings: np.ndarray | None = None

    @classmethod
    def empty(cls, dimension: int | None = None) -> ImageDetections:
        """No box (with ``(0, dimension)`` embeddings when ``dimension`` is given)."""
        emb = None if dimension is None else np.zeros((0, dimension), np.float32)
        return cls(np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0), emb)

    def __len__(self) -> int:
        return len(self.boxes)


@dataclass(frozen=True)
class DetectionsRead:
    """What :func:`read_detections` (or a bag's detection topic) gave.

    Attributes
    ----------
    images
        One :class:`ImageDetections` per image, in the order the images were given.
    boxes_read
        Boxes in the input.
    boxes_clipped
        Boxes partly outside the image, clipped to it (kept).
    boxes_dropped
        Boxes with nothing left inside the image after clipping (dropped).
    images_without_file
        Images with no detection file (YOLO) or no message at their stamp (bags): no boxes.
        A COCO JSON holds every image, so it is 0 there.
    dimension
        The embeddings' length ``D``, or ``None`` when the input has none.
    class_table
        How class names were turned into class labels (bags, whose class ids are strings);
        empty for the files, whose classes are integers.
    """

    images: tuple[ImageDetections, ...]
    boxes_read: int
    boxes_clipped: int
    boxes_dropped: int
    images_without_file: int
    dimension: int | None = None
    class_table: dict[str, int] = field(default_factory=dict)

    @property
    def boxes_kept(self) -> int:
        """Boxes in :attr:`images`: read minus dropped."""
        return self.boxes_read - self.boxes_dropped


def clip_boxes(boxes: np.ndarray, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Clip ``(M, 4)`` pixel-centre boxes to an image of ``image_size = (W, H)``.

    Returns the clipped boxes and a ``(M,)`` code per box: ``0`` inside, ``1`` clipped,
    ``2`` empty after clipping (wholly outside, or on the border with no area).
    """
    width, height = image_size
    lo = np.full(4, -0.5)
    hi = np.array([width, height, width, height], dtype=float) - 0.5
    clipped = np.clip(boxes, lo, hi)
    empty = (clipped[:, 2] <= clipped[:, 0]) | (clipped[:, 3] <= clipped[:, 1])
    moved = np.any(clipped != boxes, axis=1)
    return clipped, np.where(empty, 2, np.where(moved, 1, 0))


@dataclass
class _Box:
    image: int
    box: tuple[float, float, float, float]
    label: int
    score: float
    embedding: list[float] | None


def _assemble(
    rows: list[_Box],
    n_images: int,
    image_size: tuple[int, int],
    dimension: int | None,
    without_file: int,
    class_table: dict[str, int] | None = None,
) -> DetectionsRead:
    """Group boxes by image (input order kept), clip them, count."""
    if rows:
        boxes = np.array([r.box for r in rows], dtype=float)
        image = np.array([r.image for r in rows], dtype=np.int64)
        labels = np.array([r.label for r in rows], dtype=np.int64)
        scores = np.array([r.score for r in rows], dtype=float)
        emb = None if dimension is None else np.array([r.embedding for r in rows], np.float32)
    else:
        boxes, image = np.zeros((0, 4)), np.zeros(0, np.int64)
        labels, scores = np.zeros(0, np.int64), np.zeros(0)
        emb = None if dimension is None else np.zeros((0, dimension), np.float32)
    boxes, code = clip_boxes(boxes, image_size)
    keep = code < 2
    order = np.argsort(image, kind="stable")
    order = order[keep[order]]
    splits = np.searchsorted(image[order], np.arange(1, n_images))
    images = []
    for idx in np.split(order, splits) if n_images else []:
        images.append(
            ImageDetections(
                boxes[idx],
                labels[idx],
                scores[idx],
                None if emb is None else emb[idx].reshape(len(idx), dimension),
            )
        )
    return DetectionsRead(
        images=tuple(images),
        boxes_read=len(rows),
        boxes_clipped=int(np.count_nonzero(code == 1)),
        boxes_dropped=int(np.count_nonzero(code == 2)),
        images_without_file=without_file,
        dimension=dimension,
        class_table=dict(class_table or {}),
    )


# ----------------------------------------------------------------------------- entry point
def read_detections(
    source: str | Path,
    image_names: Sequence[str | Path],
    image_size: tuple[int, int],
    *,
    images_file: str | Path | None = None,
) -> DetectionsRead:
    """Read a detector's output for the images ``image_names`` (file names; folders ignored).

    Parameters
    ----------
    source
        A folder of YOLO ``<image stem>.txt`` files, or a COCO results ``.json`` file.
    image_names
        The images, in the order wanted; their names (or stems) are what the detection files
        refer to.
    image_size
        ``(W, H)`` of the images in pixels (YOLO coordinates are normalised by it; every box is
        clipped to it).
    images_file
        COCO only: a JSON with the COCO ``images`` list (``{"id", "file_name"}``), e.g. the
        dataset's annotation file, mapping integer ``image_id`` to image files.

    Returns
    -------
    DetectionsRead
        Per image its boxes, plus what was read, clipped, dropped and missing.
    """
    source = Path(source)
    width, height = _image_size(image_size)
    names = [PurePath(str(n)).name for n in image_names]
    dupes = _repeated(names)
    if dupes:
        raise InputError(f"image {dupes[0]!r} is given twice")
    if source.is_dir():
        if images_file is not None:
            raise InputError(f"{source}: a YOLO folder takes no images file (that is for COCO)")
        return _read_yolo(source, names, (width, height))
    if source.suffix.lower() == ".json" and source.is_file():
        return _read_coco(source, names, (width, height), images_file)
    if not source.exists():
        raise InputError(f"{source}: no such detection file or folder")
    raise InputError(f"{source}: detections are a folder of YOLO .txt files or a COCO .json file")


def _image_size(image_size: tuple[int, int]) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise InputError(f"image size must be (width, height), got {image_size!r}") from None
    if width <= 0 or height <= 0:
        raise InputError(f"image size must be positive, got {width}x{height}")
    return width, height


def _repeated(items: Iterable[str]) -> list[str]:
    seen: set[str] = set()
    return [x for x in items if x in seen or seen.add(x)]


# ----------------------------------------------------------------------------- YOLO
_INTEGER = re.compile(r"[+-]?\d+")
YOLO_LINE = "class cx cy w h [score [e_1 … e_D]]"


def _number(token: str, what: str, where: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise InputError(f"{where}: {what} {token!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{where}: {what} is {token}, not a finite number")
    return value


def _class_label(token: str, where: str) -> int:
    if not _INTEGER.fullmatch(token):
        _number(token, "class", where)
        raise InputError(f"{where}: class {token} is not an integer")
    label = int(token)
    if label < 0:
        raise InputError(f"{where}: class {label} is negative")
    return label


def _same_dimension(
    first: tuple[int, str] | None, d: int, where: str, every: str
) -> tuple[int, str]:
    """The embedding length of the first line or entry (and where it was); an
    :class:`InputError` when ``d``, at ``where``, differs from it."""
    if first is None:
        return d, where
    if d != first[0]:
        raise InputError(
            f"{where}: {d} embedding values, but {first[1]} has {first[0]} "
            f"(every {every} has the same number)"
        )
    return first


def _check_score(score: float, where: str) -> None:
    if not 0.0 <= score <= 1.0:
        raise InputError(f"{where}: score {score:g} is outside [0, 1]")


def _read_yolo(folder: Path, names: list[str], image_size: tuple[int, int]) -> DetectionsRead:
    width, height = image_size
    stems: dict[str, int] = {}
    for i, name in enumerate(names):
        stem = PurePath(name).stem
        if stem in stems:
            raise InputError(
                f"images {names[stems[stem]]!r} and {name!r} share the stem {stem!r}, "
                "so one YOLO file would name both"
            )
        stems[stem] = i
    files = sorted(p for p in folder.iterdir() if p.suffix == ".txt" and p.is_file())
    rows: list[_Box] = []
    first_d: tuple[int, str] | None = None  # (D, where it was first seen)
    found = 0
    for path in files:
        image = stems.get(path.stem)
        if image is None:
            raise InputError(
                f"{path}: detection file for no image (no image named {path.stem}.*; "
                f"the images are {_sample(names)})"
            )
        found += 1
        for k, line in enumerate(_read_text(path).splitlines(), 1):
            tokens = line.split()
            if not tokens:
                continue
            where = f"{path}, line {k}"
            if len(tokens) < 5:
                raise InputError(f"{where}: {len(tokens)} columns, a YOLO line is {YOLO_LINE}")
            label = _class_label(tokens[0], where)
            cx, cy, w, h = (
                _number(t, what, where)
                for t, what in zip(tokens[1:5], ("cx", "cy", "w", "h"), strict=True)
            )
            if w <= 0 or h <= 0:
                raise InputError(f"{where}: box size {w:g} x {h:g} is not positive")
            score = 1.0
            if len(tokens) > 5:
                score = _number(tokens[5], "score", where)
                _check_score(score, where)
            embedding = [
                _number(t, f"embedding value {j}", where) for j, t in enumerate(tokens[6:], 1)
            ]
            first_d = _same_dimension(first_d, len(embedding), where, "line of a folder")
            x_min = cx * width - w * width / 2 - 0.5
            x_max = cx * width + w * width / 2 - 0.5
            y_min = cy * height - h * height / 2 - 0.5
            y_max = cy * height + h * height / 2 - 0.5
            rows.append(_Box(image, (x_min, y_min, x_max, y_max), label, score, embedding))
    dimension = first_d[0] if first_d is not None and first_d[0] > 0 else None
    return _assemble(rows, len(names), image_size, dimension, len(names) - found)


def _sample(names: list[str], n: int = 3) -> str:
    if not names:
        return "none"
    shown = ", ".join(names[:n])
    return shown + (f", … ({len(names)} in all)" if len(names) > n else "")


# ----------------------------------------------------------------------------- COCO
def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None


def _load_json(path: Path) -> Any:
    text = _read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{path}: not valid JSON: line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _images_list(images: Any, where: str) -> dict[Any, str]:
    """``{id: file name}`` of a COCO ``images`` list."""
    if not isinstance(images, list):
        raise InputError(f'{where}: \'images\' must be a list of {{"id", "file_name"}}')
    out: dict[Any, str] = {}
    for i, item in enumerate(images):
        at = f"{where}, images[{i}]"
        if not isinstance(item, dict) or "id" not in item or "file_name" not in item:
            raise InputError(f'{at}: an image is {{"id", "file_name"}}, got {_short(item)}')
        image_id, file_name = item["id"], item["file_name"]
        if not isinstance(file_name, str) or not (
            isinstance(image_id, str)
            or (isinstance(image_id, int) and not isinstance(image_id, bool))
        ):
            raise InputError(f"{at}: id must be an integer or a string and file_name a string")
        if image_id in out:
            raise InputError(f"{at}: image id {image_id!r} is given twice")
        out[image_id] = file_name
    return out


def _short(value: Any, n: int = 60) -> str:
    text = json.dumps(value)
    return text if len(text) <= n else text[: n - 1] + "…"


class _ImageIndex:
    """Finds an image by file name, stem or (ultralytics) integer stem."""

    def __init__(self, names: list[str]):
        self.names = names
        self.by_name = {n: i for i, n in enumerate(names)}
        self.by_stem: dict[str, list[int]] = {}
        self.by_number: dict[int, list[int]] = {}
        for i, name in enumerate(names):
            stem = PurePath(name).stem
            self.by_stem.setdefault(stem, []).append(i)
            if stem.isdigit():
                self.by_number.setdefault(int(stem), []).append(i)

    def by_file(self, file_name: str, where: str) -> int:
        name = PurePath(file_name).name
        if name in self.by_name:
            return self.by_name[name]
        hits = self.by_stem.get(name) or self.by_stem.get(PurePath(name).stem)
        return self._one(hits, file_name, where)

    def by_int(self, number: int, where: str) -> int:
        return self._one(self.by_number.get(number), number, where)

    def _one(self, hits: list[int] | None, key: Any, where: str) -> int:
        if not hits:
            raise InputError(
                f"{where}: image {key!r} is none of the images ({_sample(self.names)})"
            )
        if len(hits) > 1:
            both = " and ".join(self.names[i] for i in hits[:2])
            raise InputError(f"{where}: image {key!r} could be {both}")
        return hits[0]


def _read_coco(
    path: Path, names: list[str], image_size: tuple[int, int], images_file: str | Path | None
) -> DetectionsRead:
    data = _load_json(path)
    shape = (
        "a COCO results JSON is a list of {image_id, category_id, bbox, score} "
        "or a dict with 'images' and 'annotations' (or 'detections')"
    )
    images: dict[Any, str] | None = None
    if isinstance(data, dict):
        key = next((k for k in ("annotations", "detections") if k in data), None)
        if key is None:
            raise InputError(f"{path}: {shape}; this dict has {_keys(data)}")
        entries = data[key]
        if not isinstance(entries, list):
            raise InputError(f"{path}: '{key}' must be a list")
        if "images" in data:
            images = _images_list(data["images"], str(path))
    elif isinstance(data, list):
        entries = data
    else:
        raise InputError(f"{path}: {shape}, got a JSON {type(data).__name__}")
    if images_file is not None:
        if images is not None:
            raise InputError(f"{path}: has its own 'images' list; give no images file too")
        images_path = Path(images_file)
        listing = _load_json(images_path)
        if isinstance(listing, dict) and "images" in listing:
            listing = listing["images"]
        elif not isinstance(listing, list):
            raise InputError(f"{images_path}: an images file is a COCO JSON with an 'images' list")
        images = _images_list(listing, str(images_path))

    index = _ImageIndex(names)
    resolved: dict[Any, int] = {}
    rows: list[_Box] = []
    first_d: tuple[int, str] | None = None
    for i, entry in enumerate(entries):
        where = f"{path}, entry {i}"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: an entry is a JSON object, got {_short(entry)}")
        missing = [k for k in ("image_id", "category_id", "bbox") if k not in entry]
        if missing:
            raise InputError(f"{where}: no {', '.join(missing)}")
        image_id = entry["image_id"]
        if isinstance(image_id, bool) or not isinstance(image_id, int | str):
            raise InputError(f"{where}: image_id {_short(image_id)} is not an integer or a string")
        if image_id not in resolved:
            resolved[image_id] = _coco_image(image_id, images, index, where)
        label = entry["category_id"]
        if isinstance(label, bool) or not isinstance(label, int):
            raise InputError(f"{where}: category_id {_short(label)} is not an integer")
        if label < 0:
            raise InputError(f"{where}: category_id {label} is negative")
        bbox = entry["bbox"]
        if not isinstance(bbox, list) or len(bbox) != 4 or not all(map(_is_number, bbox)):
            raise InputError(f"{where}: bbox {_short(bbox)} is not [x, y, width, height]")
        if not all(math.isfinite(v) for v in bbox):
            raise InputError(f"{where}: bbox {_short(bbox)} is not finite")
        x, y, w, h = (float(v) for v in bbox)
        if w <= 0 or h <= 0:
            raise InputError(f"{where}: box size {w:g} x {h:g} is not positive")
        score = entry.get("score", 1.0)
        if not _is_number(score) or not math.isfinite(score):
            raise InputError(f"{where}: score {_short(score)} is not a finite number")
        _check_score(float(score), where)
        embedding = entry.get("embedding")
        if embedding is not None and (
            not isinstance(embedding, list)
            or not all(map(_is_number, embedding))
            or not all(math.isfinite(v) for v in embedding)
        ):
            raise InputError(f"{where}: embedding is not a list of finite numbers")
        d = 0 if embedding is None else len(embedding)
        first_d = _same_dimension(first_d, d, where, "entry")
        box = (x - 0.5, y - 0.5, x + w - 0.5, y + h - 0.5)
        rows.append(_Box(resolved[image_id], box, label, float(score), embedding))
    dimension = first_d[0] if first_d is not None and first_d[0] > 0 else None
    return _assemble(rows, len(names), image_size, dimension, 0)


def _keys(data: Mapping) -> str:
    keys = sorted(map(str, data))
    return "keys " + ", ".join(keys) if keys else "no keys"


def _coco_image(
    image_id: Any, images: dict[Any, str] | None, index: _ImageIndex, where: str
) -> int:
    """The image an ``image_id`` names: through the ``images`` list when there is one, else a
    string is a file name or stem and an integer the number an image's stem spells (ultralytics
    writes ``int(stem)`` for numeric stems)."""
    if images is not None:
        if image_id not in images:
            raise InputError(f"{where}: image_id {image_id!r} is not in the images list")
        return index.by_file(images[image_id], where)
    if isinstance(image_id, str):
        return index.by_file(image_id, where)
    return index.by_int(image_id, where)
