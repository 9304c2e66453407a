"""Tests for the BlazePose backend: pure helpers on hand-computed cases, then the
real LiteRT models on frame 0 of the multi-person sample video.

The model files and the video come from `ringside assets pull` (the `assets` fixture).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from models.pose.blazepose import (
    BOX_ROI_SCALE,
    DETECTOR_NUM_ANCHORS,
    LANDMARKER_INPUT_SIZE,
    ROI_SCALE,
    BlazePoseDetector,
    BlazePoseLandmarker,
    Roi,
    crop_to_image,
    decode_detections,
    decode_landmarks,
    image_to_crop,
    person_box,
    roi_from_alignment,
    roi_from_box,
    sigmoid,
    ssd_anchors,
    warp_crop,
    weighted_nms,
)
from models.pose.boxes import box_iou, letterbox, nms
from models.pose.types import BLAZEPOSE_33, COCO_17, Detection, Pose

DETECTOR_FILE = "pose_detection.tflite"
LANDMARKER_FILE = "pose_landmark_full.tflite"

# BlazePose landmark indices used below.
NOSE, L_SHOULDER, R_SHOULDER = 0, 11, 12
L_HIP, R_HIP, L_KNEE, R_KNEE, L_ANKLE, R_ANKLE = 23, 24, 25, 26, 27, 28


# --------------------------------------------------------------------------
# Pure helpers, hand-computed cases
# --------------------------------------------------------------------------


def test_anchors_match_the_pose_detector_layout():
    anchors = ssd_anchors()
    # 28x28x2 (stride 8) + 14x14x2 (stride 16) + 7x7x6 (three stride-32 layers merged).
    assert anchors.shape == (DETECTOR_NUM_ANCHORS, 2) == (2254, 2)
    np.testing.assert_allclose(anchors[0], [0.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(anchors[1], anchors[0])  # 2 anchors per location
    np.testing.assert_allclose(anchors[2], [1.5 / 28, 0.5 / 28])  # then the next column
    np.testing.assert_allclose(anchors[2 * 28], [0.5 / 28, 1.5 / 28])  # then the next row
    np.testing.assert_allclose(anchors[1568], [0.5 / 14, 0.5 / 14])  # stride 16 starts
    np.testing.assert_allclose(anchors[1568 + 392 : 1568 + 392 + 6], [[0.5 / 7, 0.5 / 7]] * 6)
    np.testing.assert_allclose(anchors[-1], [6.5 / 7, 6.5 / 7])


def test_decode_detections_offsets_from_the_anchor_in_input_pixels():
    anchors = np.array([[0.5, 0.5]], dtype=np.float32)
    # cx +22.4 px, cy -11.2 px, w 44.8 px, h 22.4 px, keypoints (+11.2, 0) and (0, -22.4).
    raw = np.array([[22.4, -11.2, 44.8, 22.4, 11.2, 0.0, 0.0, -22.4]], dtype=np.float32)
    boxes, keypoints, scores = decode_detections(raw, np.array([[0.0]]), anchors, 224)
    np.testing.assert_allclose(boxes, [[0.5, 0.4, 0.7, 0.5]], atol=1e-6)
    np.testing.assert_allclose(keypoints, [[[0.55, 0.5], [0.5, 0.4]]], atol=1e-6)
    np.testing.assert_allclose(scores, [0.5])


def test_sigmoid_saturates_without_overflow():
    with np.errstate(over="raise"):
        values = sigmoid(np.array([-1000.0, 0.0, 1000.0]))
    np.testing.assert_allclose(values, [0.0, 0.5, 1.0], atol=1e-30)


def test_box_iou_hand_cases():
    boxes = np.array([[1, 1, 3, 3], [0, 0, 2, 2], [5, 5, 6, 6], [0, 0, 0, 0]], dtype=float)
    np.testing.assert_allclose(box_iou(np.array([0.0, 0, 2, 2]), boxes), [1 / 7, 1, 0, 0])


TOY_BOXES = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30]], dtype=float)
TOY_SCORES = np.array([0.8, 0.9, 0.7])  # IoU(first, second) = 81 / 119 = 0.68


def test_nms_keeps_the_best_of_overlapping_boxes():
    np.testing.assert_array_equal(nms(TOY_BOXES, TOY_SCORES, 0.5), [1, 2])
    np.testing.assert_array_equal(nms(TOY_BOXES, TOY_SCORES, 0.7), [1, 0, 2])
    assert len(nms(np.zeros((0, 4)), np.zeros(0), 0.5)) == 0


def test_weighted_nms_averages_each_cluster_by_score():
    keypoints = np.array([[[0.0, 0.0]], [[17.0, 17.0]], [[50.0, 50.0]]])
    boxes, scores, points = weighted_nms(TOY_BOXES, TOY_SCORES, keypoints, 0.5)
    w = np.array([0.9, 0.8]) / 1.7  # best first
    np.testing.assert_allclose(boxes, [w @ TOY_BOXES[[1, 0]], TOY_BOXES[2]])
    np.testing.assert_allclose(scores, [0.9, 0.7])
    np.testing.assert_allclose(points, [[[w[0] * 17, w[0] * 17]], [[50.0, 50.0]]])
    empty = weighted_nms(np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4, 2)), 0.3)
    assert [a.shape for a in empty] == [(0, 4), (0,), (0, 4, 2)]


def test_roi_from_alignment_upright_and_lying():
    upright = roi_from_alignment(np.array([100.0, 200.0]), np.array([100.0, 100.0]))
    np.testing.assert_allclose(upright.center, [100, 200])
    assert upright.size == pytest.approx(2 * 100 * ROI_SCALE)
    assert upright.rotation == pytest.approx(0.0)
    # Head to the right of the hips: the crop's top (its up) must point right.
    lying = roi_from_alignment(np.array([100.0, 100.0]), np.array([200.0, 100.0]))
    assert lying.rotation == pytest.approx(math.pi / 2)
    top_middle = crop_to_image(np.array([128.0, 0.0]), lying, 256)
    np.testing.assert_allclose(top_middle, [100 + lying.size / 2, 100], atol=1e-9)
    with pytest.raises(ValueError, match="coincide"):
        roi_from_alignment(np.array([1.0, 1.0]), np.array([1.0, 1.0]))


def test_roi_round_trip_maps_points_back_to_themselves():
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 2000, size=(50, 2))
    for rotation in (0.0, 0.3, -2.5, math.pi):
        roi = Roi(center=np.array([640.0, 480.0]), size=700.0, rotation=rotation)
        back = crop_to_image(image_to_crop(points, roi, 256), roi, 256)
        np.testing.assert_allclose(back, points, atol=1e-9)


def test_warp_crop_follows_the_analytic_mapping():
    # One bright pixel must land in the crop where image_to_crop says it does.
    image = np.zeros((400, 600, 3), dtype=np.uint8)
    image[150, 420] = 255
    original = image.copy()
    roi = Roi(center=np.array([400.0, 170.0]), size=64.0, rotation=0.7)
    crop = warp_crop(image, roi, 256)
    assert crop.shape == (256, 256, 3)
    expected = image_to_crop(np.array([420.0, 150.0]), roi, 256)
    ys, xs = np.nonzero(crop[:, :, 0])
    weights = crop[ys, xs, 0].astype(float)
    centroid = np.array([weights @ xs, weights @ ys]) / weights.sum()
    np.testing.assert_allclose(centroid, expected, atol=0.5)
    np.testing.assert_array_equal(image, original)


def test_letterbox_round_trip_and_padding():
    image = np.full((100, 50, 3), 200, dtype=np.uint8)
    square, transform = letterbox(image, 224)
    assert square.shape == (224, 224, 3)
    np.testing.assert_allclose(transform.scale, [2.24, 2.24])
    np.testing.assert_allclose(transform.pad, [56, 0])
    assert square[:, :56].max() == 0 and square[:, 56 + 112 :].max() == 0
    assert square[:, 56 : 56 + 112].min() == 200
    points = np.array([[0.0, 0.0], [50.0, 100.0], [12.5, 30.0]])
    np.testing.assert_allclose(transform.to_image(points * transform.scale + transform.pad), points)


def test_person_box_around_the_hips_and_back_to_the_same_roi():
    keypoints = np.array([[100.0, 200.0], [100.0, 100.0]])  # upright, r = 100
    np.testing.assert_allclose(person_box(keypoints), [60, 110, 140, 290])
    lying = np.array([[100.0, 200.0], [200.0, 200.0]])
    np.testing.assert_allclose(person_box(lying), [10, 160, 190, 240])
    # An upright person's box gives back the crop their keypoints give.
    from_box = roi_from_box(person_box(keypoints))
    from_points = roi_from_alignment(keypoints[0], keypoints[1])
    np.testing.assert_allclose(from_box.center, from_points.center)
    assert from_box.size == pytest.approx(from_points.size)
    assert pytest.approx(from_points.size) == BOX_ROI_SCALE * 180
    with pytest.raises(ValueError, match="keypoints"):
        person_box(np.zeros((1, 2)))
    with pytest.raises(ValueError, match="box"):
        roi_from_box(np.array([10.0, 10.0, 5.0, 20.0]))


def test_decode_landmarks_projects_and_turns_world_points():
    # A crop turned a quarter turn clockwise: its "up" is the image's +x.
    roi = Roi(center=np.array([300.0, 400.0]), size=512.0, rotation=math.pi / 2)
    raw = np.zeros((39, 5))
    raw[:, :2] = 128.0  # every landmark at the crop centre ...
    raw[1, :2] = [128.0, 0.0]  # ... but one at the crop's top middle
    raw[:, 3] = 0.0  # visibility logit 0 -> 0.5
    raw[:, 4] = 100.0  # presence logit -> 1
    world = np.zeros((39, 3))
    world[1] = [0.0, -0.5, 0.1]  # half a metre up in the crop, 10 cm away
    keypoints, visibility, presence, world_out = decode_landmarks(raw, world, roi)
    assert keypoints.shape == (33, 2) and world_out.shape == (33, 3)
    np.testing.assert_allclose(keypoints[0], [300, 400])
    np.testing.assert_allclose(keypoints[1], [300 + 256, 400], atol=1e-9)
    np.testing.assert_allclose(world_out[1], [0.5, 0.0, 0.1], atol=1e-12)
    np.testing.assert_allclose(visibility, 0.5)
    np.testing.assert_allclose(presence, 1.0)
    with pytest.raises(ValueError, match="raw_landmarks"):
        decode_landmarks(raw[:10], world[:10], roi)


def test_pose_coco17_selects_the_same_named_landmarks():
    keypoints = np.arange(66, dtype=float).reshape(33, 2)
    pose = Pose(keypoints=keypoints, confidence=np.linspace(0, 1, 33))
    points, confidence = pose.coco17()
    assert points.shape == (17, 2) and confidence.shape == (17,)
    for coco_index, name in enumerate(COCO_17):
        np.testing.assert_array_equal(points[coco_index], keypoints[BLAZEPOSE_33.index(name)])
    np.testing.assert_array_equal(points[[0, 5, 16]], keypoints[[0, 11, 28]])
    with pytest.raises(ValueError, match="coco17"):
        Pose(keypoints=np.zeros((17, 2)), confidence=np.zeros(17)).coco17()
    with pytest.raises(ValueError, match="Pose.confidence"):
        Pose(keypoints=np.zeros((33, 2)), confidence=np.zeros(32))
    with pytest.raises(ValueError, match="Detection.box"):
        Detection(box=np.zeros(3), score=1.0)


# --------------------------------------------------------------------------
# Real models on the sample video
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def detector(assets: Path) -> BlazePoseDetector:
    return BlazePoseDetector(assets / DETECTOR_FILE, num_threads=2)


@pytest.fixture(scope="module")
def landmarker(assets: Path) -> BlazePoseLandmarker:
    return BlazePoseLandmarker(assets / LANDMARKER_FILE, num_threads=2)


@pytest.fixture(scope="module")
def frame0(sample_video: Path) -> np.ndarray:
    path = sample_video
    capture = cv2.VideoCapture(str(path))
    ok, frame = capture.read()
    capture.release()
    assert ok, f"could not read frame 0 of {path}"
    frame.setflags(write=False)  # any attempt to modify it in place raises
    return frame


@pytest.fixture(scope="module")
def people(detector, frame0) -> list[Detection]:
    return detector(frame0)


def test_a_missing_model_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.tflite"):
        BlazePoseDetector(tmp_path / "missing.tflite")
    with pytest.raises(FileNotFoundError, match="missing.tflite"):
        BlazePoseLandmarker(tmp_path / "missing.tflite")
    not_a_model = tmp_path / "not_a_model.tflite"
    not_a_model.write_bytes(b"hello")
    with pytest.raises(ValueError, match="not_a_model.tflite"):
        BlazePoseLandmarker(not_a_model)


def test_errors_name_the_bad_argument(assets: Path):
    # A real model of the wrong kind is refused, naming the file.
    landmark_file = assets / LANDMARKER_FILE
    with pytest.raises(ValueError, match=LANDMARKER_FILE):
        BlazePoseDetector(landmark_file)
    with pytest.raises(ValueError, match="num_threads"):
        BlazePoseLandmarker(landmark_file, num_threads=0)
    landmarker = BlazePoseLandmarker(landmark_file, num_threads=1)
    with pytest.raises(ValueError, match="image_bgr"):
        landmarker(np.zeros((10, 10), dtype=np.uint8), np.array([0.0, 0, 5, 5]))
    with pytest.raises(ValueError, match="image_bgr"):
        landmarker(np.zeros((10, 10, 3), dtype=np.float32), np.array([0.0, 0, 5, 5]))


def test_detector_finds_nobody_in_a_black_frame(detector):
    assert detector(np.zeros((480, 640, 3), dtype=np.uint8)) == []


def test_detector_finds_the_two_people_in_frame0(people, frame0):
    height, width = frame0.shape[:2]
    assert len(people) == 2
    for person in people:
        x0, y0, x1, y1 = person.box
        assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
        aspect = (y1 - y0) / (x1 - x0)
        assert 1.2 < aspect < 4.0, f"box {person.box} is not person-shaped"
        assert (y1 - y0) > 0.3 * height  # both people are large in this frame
        assert person.score >= 0.5
        assert person.keypoints.shape == (4, 2)
        # Shoulder centre above hip centre: both stand upright.
        assert person.keypoints[2, 1] < person.keypoints[0, 1]
    assert box_iou(people[0].box, people[1].box[None])[0] < 0.3
    # One stands on the left (the man), one on the right (the woman).
    hip_x = sorted(person.keypoints[0, 0] for person in people)
    assert hip_x[0] < 0.5 * width < hip_x[1]


def test_landmarker_gives_a_confident_anatomical_pose(landmarker, people, frame0):
    for person in people:
        pose = landmarker(frame0, person)
        keypoints = pose.keypoints
        assert keypoints.shape == (33, 2) and pose.confidence.shape == (33,)
        assert pose.confidence.mean() > 0.7
        assert pose.score > 0.9
        # Points inside the person box, give or take a tenth of its size.
        margin = 0.1 * (person.box[2:] - person.box[:2])
        inside = np.all(
            (keypoints >= person.box[:2] - margin) & (keypoints <= person.box[2:] + margin), axis=1
        )
        assert inside.mean() >= 0.9
        # Head above hips above ankles (image y grows downwards).
        hips_y = keypoints[[L_HIP, R_HIP], 1].mean()
        assert keypoints[NOSE, 1] < hips_y < keypoints[[L_ANKLE, R_ANKLE], 1].mean()
        # Left and right agree down the body: if the left shoulder is right of
        # the right shoulder (facing the camera), so are the left hip and knee.
        side = np.sign(keypoints[L_SHOULDER, 0] - keypoints[R_SHOULDER, 0])
        assert np.sign(keypoints[L_HIP, 0] - keypoints[R_HIP, 0]) == side
        assert np.sign(keypoints[L_KNEE, 0] - keypoints[R_KNEE, 0]) == side
        coco_points, coco_confidence = pose.coco17()
        assert coco_points.shape == (17, 2) and coco_confidence.shape == (17,)


def test_world_landmarks_are_metric_and_follow_the_image_axes(landmarker, people, frame0):
    for person in people:
        roi = landmarker.roi_for(person)
        world = landmarker.estimate(frame0, roi).world
        assert world.shape == (33, 3)
        np.testing.assert_allclose(world[[L_HIP, R_HIP]].mean(axis=0), 0, atol=0.02)
        assert 0.2 < np.linalg.norm(world[L_SHOULDER] - world[R_SHOULDER]) < 0.5
        assert world[NOSE, 1] < 0 < world[[L_ANKLE, R_ANKLE], 1].mean()
        # Turn the crop away from upright: the world points, turned back, must
        # still point the way the image points do from the hips (left
        # uncorrected, they would be off by the extra turn).
        for extra in (0.0, -0.4, 0.4):
            pose = landmarker.estimate(frame0, replace(roi, rotation=roi.rotation + extra))
            from_hips = pose.keypoints - pose.keypoints[[L_HIP, R_HIP]].mean(axis=0)
            far = np.linalg.norm(from_hips, axis=1) > 50
            cosine = np.sum(from_hips * pose.world[:, :2], axis=1) / (
                np.linalg.norm(from_hips, axis=1) * np.linalg.norm(pose.world[:, :2], axis=1)
            )
            assert np.median(cosine[far]) > 0.98


def test_landmarker_accepts_a_plain_box(landmarker, people, frame0):
    # A tracker's box (no keypoints) gives an upright crop and a similar pose.
    for person in people:
        from_detection = landmarker(frame0, person)
        from_box = landmarker(frame0, from_detection.bbox())
        assert from_box.confidence.mean() > 0.7
        height = np.ptp(from_detection.keypoints[:, 1])
        distance = np.linalg.norm(from_box.keypoints - from_detection.keypoints, axis=1)
        assert np.median(distance) < 0.1 * height


def test_crop_has_the_model_input_form(landmarker, people, frame0):
    tensor = landmarker.preprocess(frame0, landmarker.roi_for(people[0]))
    size = LANDMARKER_INPUT_SIZE
    assert tensor.shape == (1, size, size, 3) and tensor.dtype == np.float32
    assert tensor.min() >= 0.0 and tensor.max() <= 1.0
