"""Top-down ONNX backend: an RTMDet/YOLOX person detector and an RTMPose/ViTPose
pose model, run with onnxruntime, for users who bring their own model files.

Papers whose published model formats this follows:
- RTMDet: Lyu et al., "RTMDet: An Empirical Study of Designing Real-Time Object
  Detectors", 2022. Exported with mmdeploy: input (1, 3, H, W) BGR normalised
  with the ImageNet mean/std, outputs `dets` (1, N, 5) x0, y0, x1, y1, score in
  input pixels and `labels` (1, N), NMS already inside the graph.
- YOLOX: Ge et al., "YOLOX: Exceeding YOLO Series in 2021", 2021. Exported with
  its own `export_onnx.py` (no decoding in the graph): input (1, 3, H, W) raw
  0..255 BGR, one output (1, N, 5 + C) per grid cell of strides 8, 16, 32:
  centre offsets and log sizes in stride units, sigmoided objectness and class
  scores (`decode_yolox`). An mmdeploy YOLOX export has the `dets`/`labels`
  form instead.
- RTMPose: Jiang et al., "RTMPose: Real-Time Multi-Person Pose Estimation based
  on MMPose", 2023; SimCC from Li et al., "SimCC: a Simple Coordinate
  Classification Perspective for Human Pose Estimation", ECCV 2022. Outputs
  `simcc_x` (1, K, W * r) and `simcc_y` (1, K, H * r), r the split ratio (2).
- Heatmap models (SimpleBaseline, HRNet, ViTPose: Xu et al., "ViTPose: Simple
  Vision Transformer Baselines for Human Pose Estimation", NeurIPS 2022): one
  output (1, K, h, w), usually h, w = H / 4, W / 4.

Top-down crop (the mmpose convention both pose formats were trained with): the
person box, enlarged 1.25x and widened or heightened to the model's aspect
ratio, is mapped onto the whole W x H input by a scale-and-shift affine
(`crop_affine`); its centre goes to (W / 2, H / 2). Outputs are decoded in
input pixels and mapped back with the inverse affine.

Coordinates are image pixels (x right, y down) unless a name says otherwise.
Sizes are (width, height). Shape letters: N candidate boxes, M boxes kept,
C detector classes, K pose joints, h x w heatmap, r SimCC split ratio.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType

import cv2
import numpy as np
import onnxruntime as ort
import onnxruntime.capi.onnxruntime_pybind11_state as ort_errors

from models.pose.boxes import Letterbox, check_image, letterbox, nms
from models.pose.decoders import (
    RTMPOSE_DECODER,
    OutputSpec,
    PoseDecoder,
    describe_outputs,
    dims_fit,
)
from models.pose.types import COCO_17, Detection, Pose

# onnxruntime's errors for a file it cannot read as a model.
_ORT_LOAD_ERRORS = (
    ort_errors.Fail,
    ort_errors.InvalidArgument,
    ort_errors.InvalidGraph,
    ort_errors.InvalidProtobuf,
    ort_errors.NotImplemented,
)

# YOLOX's three output strides (P3-P5).
YOLOX_STRIDES: tuple[int, ...] = (8, 16, 32)

# Top-down crop enlargement around the person box (mmpose's default padding,
# used to train RTMPose and ViTPose).
BOX_PADDING = 1.25

# Both RTMDet's and YOLOX's test pipelines pad the letterbox with grey 114.
LETTERBOX_PAD_VALUE = 114


# --------------------------------------------------------------------------
# Image normalisation
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageNormalization:
    """How a model wants its uint8 BGR pixels: tensor = (pixel - mean) / std.

    Attributes:
        mean: per-channel mean, in the channel order the model sees.
        std: per-channel standard deviation, same order.
        to_rgb: swap BGR to RGB before normalising.
    """

    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    to_rgb: bool


# RTMDet (mmdet config): BGR, ImageNet mean/std in BGR order.
RTMDET_NORMALIZATION = ImageNormalization(
    mean=(103.53, 116.28, 123.675), std=(57.375, 57.12, 58.395), to_rgb=False
)
# YOLOX (Megvii's export, mmdet's YOLOX): raw 0..255 BGR.
YOLOX_NORMALIZATION = ImageNormalization(mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0), to_rgb=False)
# RTMPose and ViTPose (mmpose configs): RGB, ImageNet mean/std in RGB order.
POSE_NORMALIZATION = ImageNormalization(
    mean=(123.675, 116.28, 103.53), std=(58.395, 57.12, 57.375), to_rgb=True
)

# Named detector presets, for configs and CLI options.
DETECTOR_NORMALIZATIONS: Mapping[str, ImageNormalization] = MappingProxyType(
    {"rtmdet": RTMDET_NORMALIZATION, "yolox": YOLOX_NORMALIZATION}
)


def to_tensor(image_bgr: np.ndarray, normalization: ImageNormalization) -> np.ndarray:
    """(H, W, 3) uint8 BGR -> (1, 3, H, W) float32 normalised tensor (a new array)."""
    pixels = image_bgr[..., ::-1] if normalization.to_rgb else image_bgr
    mean = np.asarray(normalization.mean, dtype=np.float32)
    std = np.asarray(normalization.std, dtype=np.float32)
    tensor = (pixels.astype(np.float32) - mean) / std
    return np.ascontiguousarray(tensor.transpose(2, 0, 1)[None])


# --------------------------------------------------------------------------
# Detector helpers
# --------------------------------------------------------------------------


def fill_letterbox_padding(square: np.ndarray, transform: Letterbox, value: int) -> np.ndarray:
    """A copy of a `letterbox` square with its padding (zeros) set to `value`.

    Args:
        square: (S, S, C) letterboxed image.
        transform: its `Letterbox`; the image covers
            [pad, pad + scale * image_size) of the square, per axis.
        value: the fill the detector was trained with (114 for RTMDet, YOLOX).
    """
    out = np.full_like(square, value)
    x0, y0 = (int(v) for v in transform.pad)
    x1, y1 = (int(v) for v in np.rint(transform.pad + transform.scale * transform.image_size))
    out[y0:y1, x0:x1] = square[y0:y1, x0:x1]
    return out


def yolox_grid(
    input_size: tuple[int, int], strides: Sequence[int] = YOLOX_STRIDES
) -> tuple[np.ndarray, np.ndarray]:
    """YOLOX's grid cells in output order: stride by stride, rows, then columns.

    Args:
        input_size: (W, H) of the model input.
        strides: the heads' strides.

    Returns:
        cells (N, 2) integer (column, row) of each cell in its own grid, and
        cell_strides (N,) its stride, N = sum of (H // s) * (W // s).
    """
    width, height = input_size
    cells, cell_strides = [], []
    for stride in strides:
        rows, cols = np.meshgrid(
            np.arange(height // stride), np.arange(width // stride), indexing="ij"
        )
        cells.append(np.stack([cols, rows], axis=-1).reshape(-1, 2))
        cell_strides.append(np.full(rows.size, stride))
    return np.concatenate(cells).astype(np.float64), np.concatenate(cell_strides).astype(np.float64)


def decode_yolox(
    raw: np.ndarray, input_size: tuple[int, int], strides: Sequence[int] = YOLOX_STRIDES
) -> tuple[np.ndarray, np.ndarray]:
    """Decode YOLOX's raw head output (Ge et al. 2021, Sec. 2.1: anchor-free head).

    For the cell at (column, row) of stride s:
        cx = (column + dx) * s,  cy = (row + dy) * s,  w = exp(tw) * s,  h = exp(th) * s;
    a class's score is objectness * class probability (both already sigmoided).

    Args:
        raw: (N, 5 + C) dx, dy, tw, th, objectness, C class probabilities.
        input_size: (W, H) of the model input.
        strides: the heads' strides.

    Returns:
        boxes (N, 4) x0, y0, x1, y1 in input pixels, and scores (N, C).
    """
    raw = np.asarray(raw, dtype=np.float64)
    cells, cell_strides = yolox_grid(input_size, strides)
    if raw.ndim != 2 or raw.shape[1] < 6 or len(raw) != len(cells):
        raise ValueError(
            f"raw must have shape ({len(cells)}, 5 + C) for a {input_size[0]}x{input_size[1]} "
            f"input with strides {tuple(strides)}, got {raw.shape}"
        )
    stride = cell_strides[:, None]
    centre = (cells + raw[:, 0:2]) * stride
    half = np.exp(raw[:, 2:4]) * stride / 2
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    return boxes, raw[:, 4:5] * raw[:, 5:]


# --------------------------------------------------------------------------
# Top-down crop helpers
# --------------------------------------------------------------------------


def box_to_center_scale(
    box: np.ndarray, *, aspect_ratio: float, padding: float = BOX_PADDING
) -> tuple[np.ndarray, np.ndarray]:
    """The crop for a person box: its centre, and its size enlarged and fixed to an aspect.

    The box's (w, h) is multiplied by `padding`, then the shorter side (relative
    to `aspect_ratio`) is lengthened so that w / h == aspect_ratio.

    Args:
        box: (4,) x0, y0, x1, y1 pixels.
        aspect_ratio: model input width / height (192 / 256 for RTMPose-m).
        padding: enlargement of the box.

    Returns:
        center (2,) and scale (2,) width, height of the crop, pixels.
    """
    box = np.asarray(box, dtype=np.float64)
    center = (box[:2] + box[2:]) / 2
    width, height = (box[2:] - box[:2]) * padding
    if width > height * aspect_ratio:
        height = width / aspect_ratio
    else:
        width = height * aspect_ratio
    return center, np.array([width, height])


def crop_affine(center: np.ndarray, scale: np.ndarray, output_size: tuple[int, int]) -> np.ndarray:
    """(2, 3) affine taking image pixels to crop pixels.

    The crop rectangle (`center`, `scale`) fills the (W, H) output:
        q = s * (p - center) + (W, H) / 2,  s = (W, H) / scale per axis
    (equal on both axes once the aspect is fixed).
    """
    size = np.asarray(output_size, dtype=np.float64)
    factor = size / np.asarray(scale, dtype=np.float64)
    offset = size / 2 - factor * np.asarray(center, dtype=np.float64)
    return np.array([[factor[0], 0.0, offset[0]], [0.0, factor[1], offset[1]]])


def invert_affine(matrix: np.ndarray) -> np.ndarray:
    """(2, 3) inverse of a (2, 3) invertible affine: q = A p + t -> p = A^-1 (q - t)."""
    linear_inv = np.linalg.inv(matrix[:, :2])
    return np.concatenate([linear_inv, -(linear_inv @ matrix[:, 2])[:, None]], axis=1)


def apply_affine(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(..., 2) points through a (2, 3) affine -> (..., 2) points."""
    return np.asarray(points, dtype=np.float64) @ matrix[:, :2].T + matrix[:, 2]


# --------------------------------------------------------------------------
# Pose decoders
# --------------------------------------------------------------------------


# --------------------------------------------------------------------------
# onnxruntime sessions
# --------------------------------------------------------------------------


def _check_size(name: str, size: tuple[int, int]) -> tuple[int, int]:
    if len(size) != 2 or not all(isinstance(v, int | np.integer) and v > 0 for v in size):
        raise ValueError(f"{name} must be (width, height) positive ints, got {size}")
    return int(size[0]), int(size[1])


def _static(dim: object) -> int | None:
    """A declared dimension as an int, None where it is symbolic or unknown."""
    return dim if isinstance(dim, int) else None


def _load_session(
    model_path: Path, num_threads: int, providers: Sequence[str]
) -> ort.InferenceSession:
    """Open an ONNX model, raising errors that name the file."""
    if not model_path.is_file():
        raise FileNotFoundError(f"model_path: no model file at {model_path}")
    if num_threads < 1:
        raise ValueError(f"num_threads must be >= 1, got {num_threads}")
    options = ort.SessionOptions()
    options.intra_op_num_threads = num_threads
    options.inter_op_num_threads = 1
    try:
        return ort.InferenceSession(str(model_path), options, providers=list(providers))
    except _ORT_LOAD_ERRORS as error:
        raise ValueError(
            f"model_path: {model_path} is not a readable ONNX model ({error})"
        ) from error


def _image_input(
    session: ort.InferenceSession, model_path: Path, input_size: tuple[int, int]
) -> str:
    """Name of the model's one (1, 3, H, W) float input; checks a static H, W against input_size."""
    inputs = session.get_inputs()
    width, height = input_size
    want = f"one float input (1, 3, {height}, {width})"
    if len(inputs) != 1:
        raise ValueError(f"model_path: {model_path} has {len(inputs)} inputs, expected {want}")
    (spec,) = inputs
    shape = tuple(_static(d) for d in spec.shape)
    if spec.type != "tensor(float)" or not dims_fit(shape, (1, 3, None, None)):
        raise ValueError(
            f"model_path: {model_path} takes {spec.name} {tuple(spec.shape)} {spec.type}, "
            f"expected {want}"
        )
    if not dims_fit(shape, (1, 3, height, width)):
        raise ValueError(
            f"input_size: {input_size} (width, height) does not match {model_path}, whose "
            f"input {spec.name} is {tuple(spec.shape)}"
        )
    return spec.name


def _output_specs(session: ort.InferenceSession) -> list[OutputSpec]:
    return [OutputSpec(o.name, tuple(_static(d) for d in o.shape)) for o in session.get_outputs()]


# --------------------------------------------------------------------------
# Detector
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _DetsLabelsHead:
    """mmdeploy's end-to-end outputs: `dets` (1, N, 5) and `labels` (1, N)."""

    dets: str
    labels: str

    @property
    def output_names(self) -> tuple[str, ...]:
        return (self.dets, self.labels)

    def decode(
        self, outputs: Sequence[np.ndarray], input_size: tuple[int, int], person_class: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """-> person boxes (M, 4) in input pixels and scores (M,)."""
        dets, labels = (np.asarray(o) for o in outputs)
        person = labels[0].astype(np.int64) == person_class
        return dets[0, person, :4].astype(np.float64), dets[0, person, 4].astype(np.float64)


@dataclass(frozen=True)
class _YoloxRawHead:
    """YOLOX's undecoded output (1, N, 5 + C) on the stride grid (`decode_yolox`)."""

    output: str
    strides: tuple[int, ...] = YOLOX_STRIDES

    @property
    def output_names(self) -> tuple[str, ...]:
        return (self.output,)

    def decode(
        self, outputs: Sequence[np.ndarray], input_size: tuple[int, int], person_class: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """-> all cells' boxes (N, 4) in input pixels and person scores (N,)."""
        (raw,) = outputs
        boxes, scores = decode_yolox(np.asarray(raw)[0], input_size, self.strides)
        if person_class >= scores.shape[1]:
            raise ValueError(
                f"person_class {person_class} is out of range: the model scores "
                f"{scores.shape[1]} classes"
            )
        return boxes, scores[:, person_class]


def _detector_head(
    outputs: Sequence[OutputSpec],
    model_path: Path,
    input_size: tuple[int, int],
    person_class: int,
) -> _DetsLabelsHead | _YoloxRawHead:
    """Which of the two exported signatures the model has."""
    by_name = {o.name: o for o in outputs}
    dets, labels = by_name.get("dets"), by_name.get("labels")
    if dets is not None and labels is not None:
        if dims_fit(dets.shape, (1, None, 5)) and dims_fit(labels.shape, (1, None)):
            return _DetsLabelsHead(dets.name, labels.name)
    elif len(outputs) == 1 and dims_fit(outputs[0].shape, (1, None, None)):
        num_cells = len(yolox_grid(input_size)[0])
        raw = outputs[0]
        width = raw.shape[2]
        if dims_fit(raw.shape, (1, num_cells, None)) and (width is None or width >= 6):
            if width is not None and person_class >= width - 5:
                raise ValueError(
                    f"person_class {person_class} is out of range for {model_path}, "
                    f"which scores {width - 5} classes"
                )
            return _YoloxRawHead(raw.name)
    raise ValueError(
        f"model_path: {model_path} has outputs {describe_outputs(outputs)}; expected either "
        f"dets (1, N, 5) and labels (1, N) (RTMDet / mmdeploy) or one raw YOLOX output "
        f"(1, {len(yolox_grid(input_size)[0])}, 5 + C) for a {input_size[0]}x{input_size[1]} "
        f"input with strides {YOLOX_STRIDES}"
    )


class OnnxDetector:
    """A person detector from an RTMDet or YOLOX ONNX file, a `Detector`.

    The output signature picks the decoding: `dets` + `labels` (RTMDet, any
    mmdeploy export) or one raw (1, N, 5 + C) YOLOX grid output. The
    normalisation is not in the file: pass the preset the model was trained
    with (`DETECTOR_NORMALIZATIONS`).

    Not thread-safe: one instance per thread or process.
    """

    def __init__(
        self,
        model_path: Path,
        *,
        input_size: tuple[int, int] = (640, 640),
        normalization: ImageNormalization = RTMDET_NORMALIZATION,
        score_threshold: float = 0.3,
        nms_iou: float = 0.45,
        person_class: int = 0,
        pad_value: int = LETTERBOX_PAD_VALUE,
        num_threads: int = 2,
        providers: Sequence[str] = ("CPUExecutionProvider",),
    ) -> None:
        """
        Args:
            model_path: the detector .onnx file.
            input_size: (W, H) model input; square, and equal to the model's
                own size where the file fixes it.
            normalization: pixel normalisation the model expects
                (`RTMDET_NORMALIZATION`, `YOLOX_NORMALIZATION`).
            score_threshold: person boxes scoring below this (0..1) are dropped.
            nms_iou: a box overlapping a better one by more than this IoU is dropped.
            person_class: index of "person" among the model's classes (0 in COCO).
            pad_value: grey level of the letterbox padding (114 in training).
            num_threads: CPU threads for inference.
            providers: onnxruntime execution providers, in order of preference.
        """
        self.model_path = Path(model_path)
        self.input_size = _check_size("input_size", input_size)
        if self.input_size[0] != self.input_size[1]:
            raise ValueError(
                f"input_size must be square (the letterbox fits squares), got {input_size}"
            )
        if not 0 <= score_threshold <= 1:
            raise ValueError(f"score_threshold must be in 0..1, got {score_threshold}")
        if not 0 <= nms_iou <= 1:
            raise ValueError(f"nms_iou must be in 0..1, got {nms_iou}")
        if person_class < 0:
            raise ValueError(f"person_class must be >= 0, got {person_class}")
        if not 0 <= pad_value <= 255:
            raise ValueError(f"pad_value must be in 0..255, got {pad_value}")
        self.normalization = normalization
        self.score_threshold = score_threshold
        self.nms_iou = nms_iou
        self.person_class = person_class
        self.pad_value = pad_value
        self._session = _load_session(self.model_path, num_threads, providers)
        self._input_name = _image_input(self._session, self.model_path, self.input_size)
        self._head = _detector_head(
            _output_specs(self._session), self.model_path, self.input_size, person_class
        )
        self._output_names = list(self._head.output_names)

    def preprocess(self, image_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """(H, W, 3) uint8 BGR -> (1, 3, S, S) float32 letterboxed tensor, and the letterbox."""
        check_image(image_bgr)
        square, transform = letterbox(image_bgr, self.input_size[0])
        square = fill_letterbox_padding(square, transform, self.pad_value)
        return to_tensor(square, self.normalization), transform

    def infer(self, tensor: np.ndarray) -> list[np.ndarray]:
        """(1, 3, S, S) input -> the raw outputs of the model's signature."""
        return self._session.run(self._output_names, {self._input_name: tensor})

    def postprocess(self, outputs: Sequence[np.ndarray], transform: Letterbox) -> list[Detection]:
        """Person boxes -> threshold -> NMS -> image pixels, clipped to the image.

        Boxes that lie wholly in the padding (empty once clipped) are dropped.
        """
        boxes, scores = self._head.decode(outputs, self.input_size, self.person_class)
        confident = scores >= self.score_threshold
        boxes, scores = boxes[confident], scores[confident]
        keep = nms(boxes, scores, self.nms_iou)
        upper = np.tile(transform.image_size, 2)
        detections = []
        for index in keep:
            corners = transform.to_image(boxes[index].reshape(2, 2)).reshape(4)
            box = np.clip(corners, 0, upper)
            if np.all(box[2:] > box[:2]):
                detections.append(Detection(box=box, score=float(scores[index])))
        return detections

    def __call__(self, image_bgr: np.ndarray) -> list[Detection]:
        """(H, W, 3) uint8 BGR frame -> person detections, best score first."""
        tensor, transform = self.preprocess(image_bgr)
        return self.postprocess(self.infer(tensor), transform)


# --------------------------------------------------------------------------
# Pose estimator
# --------------------------------------------------------------------------


def _box_of(box: Detection | np.ndarray) -> np.ndarray:
    """(4,) float box from a Detection or an array; ValueError unless x1 > x0, y1 > y0."""
    array = np.asarray(box.box if isinstance(box, Detection) else box, dtype=np.float64)
    if array.shape != (4,) or not np.all(np.isfinite(array)) or not np.all(array[2:] > array[:2]):
        raise ValueError(
            f"box must be a Detection or (4,) finite x0, y0, x1, y1 with x1 > x0 and y1 > y0, "
            f"got {array}"
        )
    return array


class OnnxPoseEstimator:
    """A top-down pose model from an RTMPose (SimCC) or heatmap (ViTPose) ONNX file,
    a `PoseEstimator`.

    Pose.keypoints are not clipped to the image: joints of a person cut by the
    frame edge may lie outside it. Pose.confidence is the decoder's confidence
    clipped to 0..1 (raw SimCC maxima can exceed 1). Pose.score is the
    Detection's score when given one (the model has no person-presence output),
    else 1.0. Pose.world is None.

    Not thread-safe: one instance per thread or process.
    """

    def __init__(
        self,
        model_path: Path,
        *,
        input_size: tuple[int, int] = (192, 256),
        decoder: PoseDecoder = RTMPOSE_DECODER,
        joint_names: tuple[str, ...] = COCO_17,
        normalization: ImageNormalization = POSE_NORMALIZATION,
        padding: float = BOX_PADDING,
        num_threads: int = 2,
        providers: Sequence[str] = ("CPUExecutionProvider",),
    ) -> None:
        """
        Args:
            model_path: the pose .onnx file.
            input_size: (W, H) model input (RTMPose-m body: 192 x 256).
            decoder: the output format, `RTMPOSE_DECODER` (SimCC, r = 2) or
                `HEATMAP_DECODER` (ViTPose, HRNet); see `POSE_DECODERS`.
            joint_names: names of the model's K joints, in output order.
            normalization: pixel normalisation the model expects.
            padding: enlargement of the person box for the crop.
            num_threads: CPU threads for inference.
            providers: onnxruntime execution providers, in order of preference.
        """
        self.model_path = Path(model_path)
        self.input_size = _check_size("input_size", input_size)
        if not joint_names:
            raise ValueError("joint_names must name at least one joint")
        if padding <= 0:
            raise ValueError(f"padding must be positive, got {padding}")
        self.decoder = decoder
        self.joint_names = tuple(joint_names)
        self.normalization = normalization
        self.padding = padding
        self._session = _load_session(self.model_path, num_threads, providers)
        self._input_name = _image_input(self._session, self.model_path, self.input_size)
        try:
            self._output_names = list(
                decoder.select_outputs(
                    _output_specs(self._session), self.input_size, len(self.joint_names)
                )
            )
        except ValueError as error:
            raise ValueError(f"model_path: {self.model_path}: {error}") from error

    def crop_for(self, box: Detection | np.ndarray) -> np.ndarray:
        """(2, 3) affine from image pixels to model-input pixels for a person box."""
        width, height = self.input_size
        center, scale = box_to_center_scale(
            _box_of(box), aspect_ratio=width / height, padding=self.padding
        )
        return crop_affine(center, scale, self.input_size)

    def preprocess(self, image_bgr: np.ndarray, affine: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 BGR and a crop affine -> (1, 3, H', W') float32 crop tensor.

        Parts of the crop outside the image are black (zeros), as in training.
        """
        check_image(image_bgr)
        crop = cv2.warpAffine(
            image_bgr,
            affine,
            self.input_size,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        return to_tensor(crop, self.normalization)

    def infer(self, tensor: np.ndarray) -> list[np.ndarray]:
        """(1, 3, H', W') input -> the decoder's outputs, batch dimension dropped."""
        outputs = self._session.run(self._output_names, {self._input_name: tensor})
        return [output[0] for output in outputs]

    def postprocess(
        self, outputs: Sequence[np.ndarray], affine: np.ndarray, score: float = 1.0
    ) -> Pose:
        """Decode in input pixels, map back through the inverse crop affine -> Pose (K joints)."""
        keypoints, confidence = self.decoder.decode(outputs, self.input_size)
        if len(keypoints) != len(self.joint_names):
            raise ValueError(
                f"model_path: {self.model_path} gave {len(keypoints)} joints, "
                f"expected {len(self.joint_names)} (joint_names)"
            )
        return Pose(
            keypoints=apply_affine(keypoints, invert_affine(affine)),
            confidence=np.clip(confidence, 0.0, 1.0),
            score=score,
        )

    def __call__(self, image_bgr: np.ndarray, box: Detection | Pose | np.ndarray) -> Pose:
        """Pose of the person given by a Detection, their previous Pose, or a (4,) box.

        The score is the Detection's; when following a previous Pose it is the new pose's mean
        joint confidence (the model has no person-present output, and a person who left the
        crop leaves low confidences); for a plain box it is 1.
        """
        region = box.bbox() if isinstance(box, Pose) else box
        affine = self.crop_for(region)
        score = box.score if isinstance(box, Detection) else 1.0
        pose = self.postprocess(self.infer(self.preprocess(image_bgr, affine)), affine, score)
        if isinstance(box, Pose):
            pose = replace(pose, score=float(np.mean(pose.confidence)))
        return pose
