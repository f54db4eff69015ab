"""Feature tracks with persistent ids: Shi–Tomasi corners followed by pyramidal Lucas–Kanade.

Each frame the tracks are followed forward and back; a track is kept when it stays inside the
image and returns within the forward–backward threshold, and new corners with fresh ids fill
the empty parts of the image up to ``max_features``. With ``affine_refinement`` each track is
aligned to its own first appearance (affine warp, gain and offset; Shi and Tomasi's feature
monitoring), which frame-to-frame Lucas–Kanade drifts from; a track ends when its aligned patch
no longer correlates with its template (``template_ncc_min``), its warp degenerates, or it
changed by more than ``max_track_warp`` (:func:`warp_change`). Across frames the tracker did
not see (a live robot's dropped frames), a caller that knows the camera's motion says where
each track is expected, and Lucas–Kanade starts there. :meth:`FeatureTracker.state_dict` is
everything the tracker carries from one image to the next (a checkpoint's): a tracker given it
back continues exactly as the one it came from.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from teamslam.frontend._align import PatchWindow, align_patches, with_gradients
from teamslam.frontend._clock import StageClock
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.config import FrontendConfig

__all__ = ["FeatureTracker", "warp_change"]


def warp_change(A: np.ndarray) -> np.ndarray:
    """``(N, 2, 2)`` affine warps → ``(N,)`` largest ``|log σ|`` of their singular values:
    how much a patch has grown, shrunk or been sheared (0 for a rotation), unit-free."""
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.linalg.svd(np.asarray(A, float), compute_uv=False)
        change = np.abs(np.log(sigma)).max(axis=-1)
    return np.where(np.isfinite(change), change, np.inf)


class FeatureTracker:
    """Tracks corners through a sequence of grey images.

    Parameters
    ----------
    image_size
        ``(width, height)`` of the images.
    config
        Front-end settings.
    first_id
        Id of the first new track (ids then count up; :attr:`next_id` is the next free one).
    clock
        Where the CPU time of its stages is counted (a new one when not given).
    """

    def __init__(
        self,
        image_size: tuple[int, int],
        config: FrontendConfig | None = None,
        first_id: int = 0,
        clock: StageClock | None = None,
    ) -> None:
        self.config = config or FrontendConfig()
        self.clock = clock or StageClock()
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.px = self.config.pixels(self.image_size)
        self.next_id = int(first_id)
        self.ids = np.zeros(0, np.int64)
        self._age = np.zeros(0, np.int64)  # frames since a track's first sighting
        self.uv = np.zeros((0, 2), np.float32)
        self._previous: np.ndarray | None = None
        self._window = PatchWindow(self.px.lk_window // 2)
        self._template = np.zeros((0, self._window.ox.size), np.float32)
        self._A = np.zeros((0, 2, 2))
        self._photo = np.zeros((0, 2))  # gain, offset
        self._since_detection = 0  # images since corners were last looked for

    def state_dict(self) -> dict[str, np.ndarray]:
        """What the tracker carries to the next image: the next id, each track's id, age,
        position, template, warp and gain/offset, the last image (``(0, 0)`` before the
        first) and the images since corners were last looked for."""
        previous = np.zeros((0, 0), np.uint8) if self._previous is None else self._previous
        return {
            "next_id": np.array(self.next_id, np.int64),
            "ids": self.ids.copy(),
            "age": self._age.copy(),
            "uv": self.uv.copy(),
            "previous": np.array(previous),
            "template": self._template.copy(),
            "A": self._A.copy(),
            "photo": self._photo.copy(),
            "since_detection": np.array(self._since_detection, np.int64),
        }

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Continue from a :meth:`state_dict` of a tracker of the same image size and settings.

        Raises
        ------
        ValueError
            A key missing, or arrays that do not fit together or these images.
        """
        missing = {"next_id", "ids", "age", "uv", "previous", "template", "A", "photo"} - set(state)
        if missing:
            raise ValueError(f"feature tracker state without {sorted(missing)}")
        ids = np.asarray(state["ids"], np.int64).reshape(-1)
        n = ids.size
        shapes = {"age": (n,), "uv": (n, 2)}
        if self.config.affine_refinement:
            shapes.update(template=(n, self._window.ox.size), A=(n, 2, 2), photo=(n, 2))
        for key, shape in shapes.items():
            if np.shape(state[key]) != shape:
                raise ValueError(
                    f"feature tracker state: {key} of shape {np.shape(state[key])} for {n} tracks"
                )
        previous = np.asarray(state["previous"])
        width, height = self.image_size
        if previous.size and previous.shape != (height, width):
            raise ValueError(
                f"feature tracker state: a last image of {previous.shape[1]}×{previous.shape[0]} "
                f"for images of {width}×{height}"
            )
        self.next_id = int(state["next_id"])
        self.ids = ids.copy()
        self._age = np.asarray(state["age"], np.int64).copy()
        self.uv = np.array(state["uv"])
        self._previous = previous.copy() if previous.size else None
        # the arrays as they were (their dtypes too: a template may be float32 or float64)
        self._template = np.array(state["template"])
        self._A = np.array(state["A"])
        self._photo = np.array(state["photo"])
        # a state written before detection_interval existed: corners were looked for each image
        self._since_detection = int(state.get("since_detection", 0))

    def _refine(self, image_f: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Align every track's template to ``image_f`` (float32 grey; affine + gain/offset);
        return the refined points and which tracks still match their template."""
        uv, A, photo, ncc = align_patches(
            self._window,
            self._template,
            with_gradients(image_f),
            uv,
            self._A,
            self._photo,
            self.config.affine_iterations,
        )
        det = np.linalg.det(A)
        ok = (ncc >= self.config.template_ncc_min) & (det > 0.3) & (det < 3.0)
        if self.config.max_track_warp:
            ok &= warp_change(A) <= self.config.max_track_warp
        ok &= np.all(np.isfinite(uv), axis=1)
        self._A, self._photo = A, photo
        return uv, ok

    def _lk(
        self, a: np.ndarray, b: np.ndarray, pts: np.ndarray, guess: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Lucas–Kanade from ``a`` at ``pts`` into ``b`` (starting at ``guess`` when given)."""
        cv2 = require_cv2()
        win = self.px.lk_window
        extra = {}
        if guess is not None:
            extra = {
                "nextPts": np.asarray(guess, np.float32).reshape(-1, 1, 2).copy(),
                "flags": cv2.OPTFLOW_USE_INITIAL_FLOW,
            }
        out, status, _ = cv2.calcOpticalFlowPyrLK(
            a,
            b,
            pts.reshape(-1, 1, 2),
            extra.pop("nextPts", None),
            winSize=(win, win),
            maxLevel=self.config.lk_levels,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 0.001),
            **extra,
        )
        return out.reshape(-1, 2), status.ravel().astype(bool)

    def _keep(self, keep: np.ndarray) -> None:
        self.ids, self._age = self.ids[keep], self._age[keep]
        if self.config.affine_refinement:
            self._template, self._A = self._template[keep], self._A[keep]
            self._photo = self._photo[keep]

    def _inside(self, uv: np.ndarray) -> np.ndarray:
        w, h = self.image_size
        return (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)

    def _detect(self, cv2, image: np.ndarray, room: int, image_f: np.ndarray) -> None:
        """New corners with fresh ids in the parts of ``image`` away from the tracks (at most
        ``room``), refined to sub-pixel, with their templates (sampled from ``image_f``, the
        image as float32)."""
        mask = np.full(image.shape, 255, np.uint8)
        radius = max(1, round(self.px.spacing))
        for u, v in np.rint(self.uv).astype(int):
            cv2.circle(mask, (int(u), int(v)), radius, 0, -1)
        border = self.px.lk_window // 2
        mask[:border], mask[-border:], mask[:, :border], mask[:, -border:] = 0, 0, 0, 0
        corners = cv2.goodFeaturesToTrack(
            image,
            maxCorners=room,
            qualityLevel=self.config.corner_quality,
            minDistance=self.px.spacing,
            mask=mask,
            blockSize=self.px.corner_block,
        )
        if corners is not None:
            new = corners.reshape(-1, 2).astype(np.float32)
            win = max(2, self.px.corner_block // 2)
            cv2.cornerSubPix(
                image,
                new,
                (win, win),
                (-1, -1),
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01),
            )
            fresh = self.next_id + np.arange(len(new), dtype=np.int64)
            self.next_id += len(new)
            self.ids = np.concatenate([self.ids, fresh])
            self._age = np.concatenate([self._age, np.zeros(len(new), np.int64)])
            self.uv = np.concatenate([self.uv, new])
            if self.config.affine_refinement:
                eye = np.tile(np.eye(2), (len(new), 1, 1))
                tmpl = self._window.sample(image_f, new, eye)
                self._template = np.concatenate([self._template, tmpl])
                self._A = np.concatenate([self._A, eye])
                self._photo = np.concatenate([self._photo, np.tile([1.0, 0.0], (len(new), 1))])

    def track(
        self,
        image: np.ndarray,
        predict: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
        image_f: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Follow the tracks into ``image`` (8-bit grey) and refill; return ``(ids, uv)``.

        ``predict(ids, uv)``: where the tracks at ``uv`` in the previous image are expected in
        this one (e.g. by the camera's motion over frames dropped in between), ``(N, 2)``; Lucas–
        Kanade starts there instead of at ``uv``, and the backward check at ``uv``. ``image_f``:
        the image as float32, when the caller has it (converted here otherwise)."""
        cv2 = require_cv2()
        if image_f is None:
            image_f = image.astype(np.float32)
        if self.config.max_track_length and len(self.ids):
            young = self._age + 1 < self.config.max_track_length
            self._keep(young)
            self.uv = self.uv[young]
        clock = self.clock
        if self._previous is not None and len(self.ids):
            self._age += 1
            guess = None if predict is None else predict(self.ids, self.uv)
            with clock.stage("temporal LK"):
                fwd, ok_f = self._lk(self._previous, image, self.uv, guess)
                back, ok_b = self._lk(
                    image, self._previous, fwd, None if guess is None else self.uv
                )
            fb = np.linalg.norm(back - self.uv, axis=1)
            keep = ok_f & ok_b & (fb <= self.px.forward_backward) & self._inside(fwd)
            self._keep(keep)
            self.uv = fwd[keep].astype(np.float32)
            if self.config.affine_refinement and len(self.ids):
                with clock.stage("track alignment"):
                    refined, ok = self._refine(image_f, self.uv)
                ok &= np.linalg.norm(refined - self.uv, axis=1) <= self.px.refine_track
                ok &= self._inside(refined)
                self.uv = refined.astype(np.float32)
                self._keep(ok)
                self.uv = self.uv[ok]
        elif self._previous is None:
            self.ids, self.uv = np.zeros(0, np.int64), np.zeros((0, 2), np.float32)
            self._age = np.zeros(0, np.int64)
        room = self.config.max_features - len(self.ids)
        due = self._previous is None or self._since_detection + 1 >= self.config.detection_interval
        if room > 0 and due:
            with clock.stage("feature detection"):
                self._detect(cv2, image, room, image_f)
            self._since_detection = 0
        else:
            self._since_detection += 1
        self._previous = image
        return self.ids.copy(), self.uv.astype(np.float64)
