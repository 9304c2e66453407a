"""Tests for the ONNX top-down backend: pure helpers on hand-computed cases, then
tiny ONNX models built here with the published input/output signatures, whose
outputs are fixed (or derived from the input in an obvious way), so that every
decoded box and joint has a known answer.

Building the models needs the `onnx` package (a dev dependency); the tests of
the pure helpers run without it.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from models.pose.boxes import letterbox
from models.pose.decoders import (
    HEATMAP_DECODER,
    POSE_DECODERS,
    RTMPOSE_DECODER,
    decode_heatmap,
    decode_simcc,
)
from models.pose.onnx_backend import (
    DETECTOR_NORMALIZATIONS,
    POSE_NORMALIZATION,
    RTMDET_NORMALIZATION,
    YOLOX_NORMALIZATION,
    OnnxDetector,
    OnnxPoseEstimator,
    apply_affine,
    box_to_center_scale,
    crop_affine,
    decode_yolox,
    fill_letterbox_padding,
    invert_affine,
    to_tensor,
    yolox_grid,
)
from models.pose.types import COCO_17, Detection, Detector, Pose, PoseEstimator

POSE_W, POSE_H = 192, 256  # RTMPose-m body input
SPLIT = 2  # SimCC split ratio
K = len(COCO_17)


# --------------------------------------------------------------------------
# Building tiny ONNX models
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def onnx():
    return pytest.importorskip("onnx", reason="building test models needs the onnx package")


def save_model(onnx, path: Path, nodes, inputs, outputs) -> Path:
    """Write a graph (opset 17) to `path`."""
    graph = onnx.helper.make_graph(nodes, path.stem, inputs, outputs)
    model = onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 17)])
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def image_input(onnx, shape, name: str = "input"):
    return onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, list(shape))


def constant_model(onnx, path: Path, input_shape, outputs: dict[str, np.ndarray]) -> Path:
    """A model with one image input that it ignores, and constant outputs."""
    nodes, infos = [], []
    for name, value in outputs.items():
        tensor = onnx.numpy_helper.from_array(value, name=f"{name}_value")
        nodes.append(onnx.helper.make_node("Constant", [], [name], value=tensor))
        dtype = onnx.helper.np_dtype_to_tensor_dtype(value.dtype)
        infos.append(onnx.helper.make_tensor_value_info(name, dtype, list(value.shape)))
    return save_model(onnx, path, nodes, [image_input(onnx, input_shape)], infos)


def one_hot_simcc(bins: np.ndarray, length: int, peak: float = 0.9) -> np.ndarray:
    """(1, K, length) SimCC output with `peak` at bins[k] for joint k, 0.1 elsewhere."""
    out = np.full((1, len(bins), length), 0.1, dtype=np.float32)
    out[0, np.arange(len(bins)), bins] = peak
    return out


def simcc_model(onnx, path: Path, x_bins, y_bins, x_peak=0.9, y_peak=0.9) -> Path:
    """An RTMPose-signature model whose joints all lie at fixed SimCC bins."""
    return constant_model(
        onnx,
        path,
        ("batch", 3, POSE_H, POSE_W),
        {
            "simcc_x": one_hot_simcc(np.asarray(x_bins), POSE_W * SPLIT, x_peak),
            "simcc_y": one_hot_simcc(np.asarray(y_bins), POSE_H * SPLIT, y_peak),
        },
    )


def bright_spot_simcc_model(onnx, path: Path) -> Path:
    """An RTMPose-signature model that "finds" the brightest pixel of its input.

    simcc_x[k, 2i] = simcc_x[k, 2i + 1] = max over channels and rows of column i
    (likewise simcc_y over columns), so argmax / 2 is the brightest pixel's
    column (row) for every joint.
    """
    helper = onnx.helper

    def const(name, value):
        tensor = onnx.numpy_helper.from_array(np.asarray(value, dtype=np.int64), name=name)
        return helper.make_node("Constant", [], [name], value=tensor)

    nodes = [
        const("expand_shape", [1, K, 1]),
        const("axis_1", [1]),
        const("axis_3", [3]),
        const("flat_shape", [1, K, -1]),
    ]
    for axis, reduce_axes in (("x", [1, 2]), ("y", [1, 3])):
        nodes += [
            helper.make_node("ReduceMax", ["input"], [f"{axis}_p"], axes=reduce_axes, keepdims=0),
            helper.make_node("Unsqueeze", [f"{axis}_p", "axis_1"], [f"{axis}_1"]),
            helper.make_node("Expand", [f"{axis}_1", "expand_shape"], [f"{axis}_k"]),
            helper.make_node("Unsqueeze", [f"{axis}_k", "axis_3"], [f"{axis}_k1"]),
            helper.make_node("Concat", [f"{axis}_k1", f"{axis}_k1"], [f"{axis}_k2"], axis=3),
            helper.make_node("Reshape", [f"{axis}_k2", "flat_shape"], [f"simcc_{axis}"]),
        ]
    outputs = [
        helper.make_tensor_value_info("simcc_x", onnx.TensorProto.FLOAT, [1, K, POSE_W * SPLIT]),
        helper.make_tensor_value_info("simcc_y", onnx.TensorProto.FLOAT, [1, K, POSE_H * SPLIT]),
    ]
    return save_model(onnx, path, nodes, [image_input(onnx, (1, 3, POSE_H, POSE_W))], outputs)


def expected_joint(box, bin_x: float, bin_y: float) -> np.ndarray:
    """Reference mapping, written out: SimCC bin -> input pixel -> image pixel.

    The crop is the box enlarged 1.25x and widened or heightened to 3:4; its
    centre sits at the input's centre, one input pixel spanning crop_w / 192
    image pixels.
    """
    x0, y0, x1, y1 = box
    w, h = (x1 - x0) * 1.25, (y1 - y0) * 1.25
    if w / h > POSE_W / POSE_H:
        h = w * POSE_H / POSE_W
    else:
        w = h * POSE_W / POSE_H
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return np.array(
        [
            cx + (bin_x / SPLIT - POSE_W / 2) * w / POSE_W,
            cy + (bin_y / SPLIT - POSE_H / 2) * h / POSE_H,
        ]
    )


# --------------------------------------------------------------------------
# Pure helpers
# --------------------------------------------------------------------------


def test_presets_hold_the_published_normalisations():
    assert DETECTOR_NORMALIZATIONS["rtmdet"] is RTMDET_NORMALIZATION
    assert DETECTOR_NORMALIZATIONS["yolox"] is YOLOX_NORMALIZATION
    assert RTMDET_NORMALIZATION.mean == (103.53, 116.28, 123.675)
    assert RTMDET_NORMALIZATION.std == (57.375, 57.12, 58.395)
    assert not RTMDET_NORMALIZATION.to_rgb and not YOLOX_NORMALIZATION.to_rgb
    assert POSE_NORMALIZATION.to_rgb and POSE_NORMALIZATION.mean == (123.675, 116.28, 103.53)
    assert POSE_DECODERS["simcc"] is RTMPOSE_DECODER and RTMPOSE_DECODER.split_ratio == 2.0
    assert POSE_DECODERS["heatmap"] is HEATMAP_DECODER
    with pytest.raises(TypeError):
        DETECTOR_NORMALIZATIONS["mine"] = YOLOX_NORMALIZATION  # read-only mapping


def test_to_tensor_normalises_and_swaps_channels_without_touching_the_image():
    image = np.zeros((2, 3, 3), np.uint8)
    image[..., 0] = 10  # B
    image[..., 2] = 200  # R
    before = image.copy()
    bgr = to_tensor(image, RTMDET_NORMALIZATION)
    rgb = to_tensor(image, POSE_NORMALIZATION)
    assert bgr.shape == rgb.shape == (1, 3, 2, 3) and bgr.dtype == np.float32
    np.testing.assert_allclose(bgr[0, 0], (10 - 103.53) / 57.375, rtol=1e-6)
    np.testing.assert_allclose(rgb[0, 0], (200 - 123.675) / 58.395, rtol=1e-6)  # R first
    np.testing.assert_allclose(rgb[0, 2], (10 - 103.53) / 57.375, rtol=1e-6)
    np.testing.assert_allclose(to_tensor(image, YOLOX_NORMALIZATION)[0, 2], 200)
    np.testing.assert_array_equal(image, before)


def test_letterbox_padding_is_filled_and_the_image_kept():
    image = np.full((20, 40, 3), 7, np.uint8)  # wide: padded above and below
    square, transform = letterbox(image, 80)
    filled = fill_letterbox_padding(square, transform, 114)
    # 40x20 -> 80x40, 20 rows of padding above and below.
    np.testing.assert_array_equal(filled[:20], 114)
    np.testing.assert_array_equal(filled[60:], 114)
    np.testing.assert_array_equal(filled[20:60], 7)
    np.testing.assert_array_equal(square[:20], 0)  # input untouched


def test_yolox_grid_orders_strides_then_rows_then_columns():
    cells, strides = yolox_grid((64, 32))  # W=64, H=32
    # stride 8: 4 rows x 8 cols; stride 16: 2 x 4; stride 32: 1 x 2.
    assert len(cells) == 32 + 8 + 2
    np.testing.assert_array_equal(cells[:3], [[0, 0], [1, 0], [2, 0]])
    np.testing.assert_array_equal(cells[8], [0, 1])  # second row of stride 8
    np.testing.assert_array_equal(cells[32 + 5], [1, 1])  # stride 16, row 1, col 1
    np.testing.assert_array_equal(strides[[0, 31, 32, 39, 40, 41]], [8, 8, 16, 16, 32, 32])


def test_decode_yolox_on_a_hand_computed_cell():
    # 64x64 input: 8x8 cells of stride 8 (0..63), 4x4 of 16 (64..79), 2x2 of 32.
    raw = np.zeros((84, 7))
    # Stride 16, row 1, column 2 -> index 64 + 1 * 4 + 2 = 70.
    raw[70] = [0.5, 0.25, math.log(2), math.log(3), 0.8, 0.5, 0.9]
    boxes, scores = decode_yolox(raw, (64, 64))
    # cx = (2 + 0.5) * 16 = 40, cy = (1 + 0.25) * 16 = 20, w = 2 * 16, h = 3 * 16.
    np.testing.assert_allclose(boxes[70], [40 - 16, 20 - 24, 40 + 16, 20 + 24])
    np.testing.assert_allclose(scores[70], [0.8 * 0.5, 0.8 * 0.9])
    # Cell 0 (stride 8, at the origin) with zero offsets: a 8x8 box centred on (0, 0).
    np.testing.assert_allclose(boxes[0], [-4, -4, 4, 4])
    with pytest.raises(ValueError, match="raw must have shape"):
        decode_yolox(raw[:80], (64, 64))


def test_box_to_center_scale_pads_and_fixes_the_aspect():
    # Tall box: 60x200 -> 75x250 -> widened to 187.5x250 (3:4).
    center, scale = box_to_center_scale(np.array([100, 50, 160, 250]), aspect_ratio=0.75)
    np.testing.assert_allclose(center, [130, 150])
    np.testing.assert_allclose(scale, [187.5, 250])
    # Wide box: 200x60 -> 250x75 -> heightened to 250x333.33.
    _, scale = box_to_center_scale(np.array([20, 40, 220, 100]), aspect_ratio=0.75)
    np.testing.assert_allclose(scale, [250, 250 / 0.75])


def test_crop_affine_maps_the_crop_onto_the_input_and_back():
    center, scale = np.array([130.0, 150.0]), np.array([187.5, 250.0])
    affine = crop_affine(center, scale, (192, 256))
    corners = np.array([[130 - 93.75, 150 - 125], [130 + 93.75, 150 + 125], [130, 150]])
    np.testing.assert_allclose(
        apply_affine(corners, affine), [[0, 0], [192, 256], [96, 128]], atol=1e-9
    )
    back = apply_affine(apply_affine(corners, affine), invert_affine(affine))
    np.testing.assert_allclose(back, corners)
    np.testing.assert_allclose(invert_affine(invert_affine(affine)), affine)


def test_decode_simcc_takes_argmax_over_ratio_and_the_smaller_maximum():
    simcc_x = np.zeros((2, 10))
    simcc_y = np.zeros((2, 12))
    simcc_x[0, 7], simcc_y[0, 4] = 0.9, 0.6
    simcc_x[1, 0], simcc_y[1, 11] = 0.3, 0.8
    keypoints, confidence = decode_simcc(simcc_x, simcc_y, 2.0)
    np.testing.assert_allclose(keypoints, [[3.5, 2.0], [0.0, 5.5]])
    np.testing.assert_allclose(confidence, [0.6, 0.3])
    with pytest.raises(ValueError, match="simcc_x and simcc_y"):
        decode_simcc(simcc_x, simcc_y[:1], 2.0)


def test_decode_heatmap_shifts_a_quarter_pixel_towards_the_higher_neighbour():
    heatmaps = np.zeros((3, 64, 48))
    # Joint 0: peak (x=10, y=20); right 0.5 > left 0.3 -> +0.25; above 0.6 > below 0.4 -> -0.25.
    heatmaps[0, 20, 10] = 0.9
    heatmaps[0, 20, 11], heatmaps[0, 20, 9] = 0.5, 0.3
    heatmaps[0, 19, 10], heatmaps[0, 21, 10] = 0.6, 0.4
    # Joint 1: peak on the left edge (x=0), y neighbours equal: no shift at all.
    heatmaps[1, 30, 0] = 0.7
    heatmaps[1, 30, 1] = 0.2
    heatmaps[1, 29, 0] = heatmaps[1, 31, 0] = 0.1
    # Joint 2: peak in the bottom-right corner (x = w - 1, y = h - 1): a neighbour is missing
    # on each axis, so no shift even though the left neighbour is high.
    heatmaps[2, 63, 47] = 0.5
    heatmaps[2, 63, 46] = 0.4
    keypoints, confidence = decode_heatmap(heatmaps)
    np.testing.assert_allclose(keypoints, [[10.25, 19.75], [0, 30], [47, 63]])
    np.testing.assert_allclose(confidence, [0.9, 0.7, 0.5])
    # Heatmap pixels scale to input pixels by input / heatmap size (4 here).
    input_px, _ = HEATMAP_DECODER.decode([heatmaps], (192, 256))
    np.testing.assert_allclose(input_px[0], [41, 79])


# --------------------------------------------------------------------------
# Pose estimator on tiny models
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "box",
    [
        (100.0, 50.0, 160.0, 250.0),  # tall box inside the image
        (-10.0, 5.0, 30.0, 45.0),  # square box over the left edge
        (20.0, 40.0, 220.0, 100.0),  # wide (non-square) box
        (260.0, 150.0, 319.0, 239.0),  # box in the bottom-right corner
    ],
)
def test_simcc_joints_land_at_the_known_image_pixel(onnx, tmp_path, box):
    x_bins = np.arange(K) * 20 + 3  # 3 .. 323 of 384
    y_bins = 500 - np.arange(K) * 25  # 500 .. 100 of 512
    model = simcc_model(onnx, tmp_path / "rtmpose.onnx", x_bins, y_bins, 0.9, 0.7)
    estimator = OnnxPoseEstimator(model)
    image = np.zeros((240, 320, 3), np.uint8)
    pose = estimator(image, np.array(box))
    assert isinstance(pose, Pose) and pose.world is None and pose.score == 1.0
    assert pose.keypoints.shape == (K, 2) and pose.confidence.shape == (K,)
    want = np.stack([expected_joint(box, bx, by) for bx, by in zip(x_bins, y_bins, strict=True)])
    np.testing.assert_allclose(pose.keypoints, want, atol=0.5)
    np.testing.assert_allclose(pose.confidence, 0.7, rtol=1e-6)  # min(0.9, 0.7)


def test_simcc_hand_computed_joint(onnx, tmp_path):
    # Box (100, 50)-(160, 250): crop 187.5 x 250 centred on (130, 150), 0.9765625 px per input px.
    # Bin (200, 100) -> input (100, 50) -> image (130 + 4 * 0.9765625, 150 - 78 * 0.9765625).
    model = simcc_model(onnx, tmp_path / "rtmpose.onnx", [200] * K, [100] * K)
    detection = Detection(box=np.array([100.0, 50.0, 160.0, 250.0]), score=0.8)
    pose = OnnxPoseEstimator(model)(np.zeros((300, 300, 3), np.uint8), detection)
    np.testing.assert_allclose(pose.keypoints[0], [133.90625, 73.828125], atol=1e-4)
    assert pose.score == pytest.approx(0.8)  # the detection's score


def test_confidence_is_clipped_to_unit_range(onnx, tmp_path):
    model = simcc_model(onnx, tmp_path / "rtmpose.onnx", [10] * K, [10] * K, 1.7, 1.4)
    pose = OnnxPoseEstimator(model)(np.zeros((64, 64, 3), np.uint8), np.array([0, 0, 30, 40.0]))
    np.testing.assert_allclose(pose.confidence, 1.0)


def test_crop_warp_and_inverse_agree_end_to_end(onnx, tmp_path):
    """A model that reports its input's brightest pixel finds a lone bright image pixel again."""
    estimator = OnnxPoseEstimator(bright_spot_simcc_model(onnx, tmp_path / "spot.onnx"))
    # Box 60 x 80 -> crop 75 x 100 image px (x 32.5..107.5, y 20..120) on the 192 x 256 input.
    box = np.array([40.0, 30.0, 100.0, 110.0])
    for spot in [(70, 70), (45, 35), (98, 105), (34, 22)]:
        image = np.zeros((160, 200, 3), np.uint8)
        image[spot[1], spot[0]] = 255
        before = image.copy()
        pose = estimator(image, box)
        # The crop samples 0.39 image px apart: its brightest pixel is within 0.2 px.
        np.testing.assert_allclose(pose.keypoints, np.tile(spot, (K, 1)), atol=0.3)
        np.testing.assert_array_equal(image, before)


def test_heatmap_model_decodes_to_the_known_image_pixel(onnx, tmp_path):
    heatmaps = np.zeros((1, K, 64, 48), np.float32)
    heatmaps[0, :, 20, 10] = 0.9
    heatmaps[0, :, 20, 11] = 0.5  # right neighbour higher: x + 0.25
    heatmaps[0, :, 21, 10] = 0.5  # lower neighbour higher: y + 0.25
    model = constant_model(onnx, tmp_path / "vitpose.onnx", (1, 3, 256, 192), {"output": heatmaps})
    estimator = OnnxPoseEstimator(model, decoder=HEATMAP_DECODER)
    box = (100.0, 50.0, 160.0, 250.0)
    pose = estimator(np.zeros((300, 300, 3), np.uint8), np.array(box))
    # Heatmap (10.25, 20.25) -> input (41, 81) = SimCC bins (82, 162).
    np.testing.assert_allclose(pose.keypoints, np.tile(expected_joint(box, 82, 162), (K, 1)))
    np.testing.assert_allclose(pose.confidence, 0.9, rtol=1e-6)


def test_pose_estimator_rejects_bad_models_images_and_boxes(onnx, tmp_path):
    not_onnx = tmp_path / "notes.onnx"
    not_onnx.write_text("not a model")
    with pytest.raises(ValueError, match="notes.onnx is not a readable ONNX model"):
        OnnxPoseEstimator(not_onnx)
    with pytest.raises(FileNotFoundError, match="model_path"):
        OnnxPoseEstimator(tmp_path / "missing.onnx")
    simcc = simcc_model(onnx, tmp_path / "rtmpose.onnx", [0] * K, [0] * K)
    # A SimCC model read as a heatmap model, or with the wrong joint count / input size.
    with pytest.raises(ValueError, match=r"rtmpose.onnx.*heatmap output \(1, 17, h, w\)"):
        OnnxPoseEstimator(simcc, decoder=HEATMAP_DECODER)
    with pytest.raises(ValueError, match=r"simcc_x \(1, 133, 384\)"):
        OnnxPoseEstimator(simcc, joint_names=tuple(f"j{i}" for i in range(133)))
    with pytest.raises(ValueError, match="input_size"):
        OnnxPoseEstimator(simcc, input_size=(288, 384))
    estimator = OnnxPoseEstimator(simcc)
    box = np.array([0, 0, 10, 10.0])
    with pytest.raises(ValueError, match=r"image_bgr must be an \(H, W, 3\)"):
        estimator(np.zeros((32, 32), np.uint8), box)
    with pytest.raises(ValueError, match="image_bgr must be uint8"):
        estimator(np.zeros((32, 32, 3), np.float32), box)
    with pytest.raises(ValueError, match="box must be"):
        estimator(np.zeros((32, 32, 3), np.uint8), np.array([10, 0, 5, 10.0]))


# --------------------------------------------------------------------------
# Detector on tiny models
# --------------------------------------------------------------------------


def rtmdet_model(onnx, path: Path, dets: list[list[float]], labels: list[int]) -> Path:
    """An mmdeploy-signature detector returning fixed dets (input pixels) and labels."""
    return constant_model(
        onnx,
        path,
        (1, 3, 640, 640),
        {
            "dets": np.array([dets], np.float32),
            "labels": np.array([labels], np.int64),
        },
    )


def test_rtmdet_boxes_map_back_through_the_letterbox(onnx, tmp_path):
    # A 320x160 image letterboxes into 640x640 at scale 2 with 160 rows of padding above:
    # image (x, y) = (input x / 2, (input y - 160) / 2).
    dets = [
        [100, 200, 300, 400, 0.9],  # person
        [104, 204, 304, 404, 0.8],  # its duplicate: NMS drops it
        [400, 180, 500, 420, 0.6],  # a second person
        [0, 160, 640, 480, 0.95],  # a car (label 2): dropped
        [500, 200, 600, 300, 0.1],  # below the score threshold
        [10, 10, 60, 100, 0.7],  # wholly in the padding: empty once clipped
    ]
    model = rtmdet_model(onnx, tmp_path / "rtmdet.onnx", dets, [0, 0, 0, 2, 0, 0])
    detector = OnnxDetector(model)
    detections = detector(np.zeros((160, 320, 3), np.uint8))
    assert [d.score for d in detections] == pytest.approx([0.9, 0.6])
    np.testing.assert_allclose(detections[0].box, [50, 20, 150, 120])
    # (400, 180)-(500, 420) -> (200, 10)-(250, 130).
    np.testing.assert_allclose(detections[1].box, [200, 10, 250, 130])
    assert all(isinstance(d, Detection) and d.keypoints is None for d in detections)


def test_rtmdet_preprocess_letterboxes_with_grey_padding(onnx, tmp_path):
    model = rtmdet_model(onnx, tmp_path / "rtmdet.onnx", [[0, 0, 1, 1, 0.0]], [0])
    detector = OnnxDetector(model)
    image = np.full((160, 320, 3), 200, np.uint8)
    tensor, transform = detector.preprocess(image)
    assert tensor.shape == (1, 3, 640, 640) and tensor.dtype == np.float32
    np.testing.assert_allclose(transform.pad, [0, 160])
    np.testing.assert_allclose(tensor[0, 0, 0, 0], (114 - 103.53) / 57.375, rtol=1e-5)
    np.testing.assert_allclose(tensor[0, 0, 320, 320], (200 - 103.53) / 57.375, rtol=1e-5)
    assert detector(image) == []  # nothing above the threshold


def test_yolox_raw_grid_output_decodes_to_image_boxes(onnx, tmp_path):
    # 64x64 input, 84 cells (see test_decode_yolox_on_a_hand_computed_cell), 2 classes.
    raw = np.zeros((1, 84, 7), np.float32)
    raw[0, 70] = [0.5, 0.25, math.log(2), math.log(3), 0.8, 0.5, 0.9]  # person 0.4
    raw[0, 71] = [0.5, 0.25, math.log(2), math.log(3), 0.8, 0.45, 0.9]  # duplicate, 0.36
    raw[0, 5] = [0.5, 0.5, 0, 0, 0.9, 0.1, 0.95]  # class 1 (person score 0.09): dropped
    model = constant_model(onnx, tmp_path / "yolox.onnx", (1, 3, 64, 64), {"output": raw})
    detector = OnnxDetector(model, input_size=(64, 64), normalization=YOLOX_NORMALIZATION)
    # Cell 71 is one column right: box (40, -4, 72, 44); IoU with cell 70's is 1/3 < 0.45.
    detections = detector(np.zeros((128, 128, 3), np.uint8))  # image = input * 2
    assert [d.score for d in detections] == pytest.approx([0.4, 0.36])
    np.testing.assert_allclose(detections[0].box, [48, 0, 112, 88])  # (24, -4, 56, 44) * 2
    strict = OnnxDetector(model, input_size=(64, 64), nms_iou=0.3)
    assert len(strict(np.zeros((128, 128, 3), np.uint8))) == 1


def test_detector_rejects_bad_models_sizes_and_images(onnx, tmp_path):
    not_onnx = tmp_path / "weights.onnx"
    not_onnx.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ValueError, match="weights.onnx is not a readable ONNX model"):
        OnnxDetector(not_onnx)
    odd = constant_model(
        onnx, tmp_path / "odd.onnx", (1, 3, 640, 640), {"scores": np.zeros((1, 10), np.float32)}
    )
    with pytest.raises(ValueError, match=r"odd.onnx has outputs scores \(1, 10\); expected"):
        OnnxDetector(odd)
    model = rtmdet_model(onnx, tmp_path / "rtmdet.onnx", [[0, 0, 1, 1, 0.0]], [0])
    with pytest.raises(ValueError, match="input_size"):
        OnnxDetector(model, input_size=(320, 320))
    with pytest.raises(ValueError, match="input_size must be square"):
        OnnxDetector(model, input_size=(640, 480))
    yolox = constant_model(
        onnx, tmp_path / "yolox.onnx", (1, 3, 64, 64), {"output": np.zeros((1, 84, 7), np.float32)}
    )
    with pytest.raises(ValueError, match="person_class 2 is out of range"):
        OnnxDetector(yolox, input_size=(64, 64), person_class=2)
    with pytest.raises(ValueError, match="image_bgr"):
        OnnxDetector(model)(np.zeros((10, 10, 4), np.uint8))


# --------------------------------------------------------------------------
# Interface
# --------------------------------------------------------------------------


def test_classes_satisfy_the_backend_protocols(onnx, tmp_path):
    detector: Detector = OnnxDetector(
        rtmdet_model(onnx, tmp_path / "rtmdet.onnx", [[8, 168, 40, 232, 0.9]], [0])
    )
    estimator: PoseEstimator = OnnxPoseEstimator(
        simcc_model(onnx, tmp_path / "rtmpose.onnx", [0] * K, [0] * K)
    )
    for cls, proto in ((OnnxDetector, Detector), (OnnxPoseEstimator, PoseEstimator)):
        ours = list(inspect.signature(cls.__call__).parameters)
        theirs = list(inspect.signature(proto.__call__).parameters)
        assert ours == theirs
    image = cv2.cvtColor(np.zeros((160, 320), np.uint8), cv2.COLOR_GRAY2BGR)
    (detection,) = detector(image)
    pose = estimator(image, detection)
    assert isinstance(pose, Pose) and len(pose.keypoints) == len(COCO_17)
