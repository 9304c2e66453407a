"""The two tests that fail, each once and saying why, when the bundled sample cannot serve the
suite: every test on the sample's data directory (`sample_run`) or on its dataset skips with the
same words. Before, two steps the lift dropped split the sample's only interaction clip and 16
tests failed or errored, each with training's advice to lower dataset.min_clip_s."""

from __future__ import annotations

from conftest import sample_training


def test_the_sample_goes_through_every_stage(sample_processing):
    _, problem = sample_processing
    assert problem is None, problem


def test_the_sample_can_be_trained_on(sample_run):
    _, problem = sample_training(sample_run)
    assert problem is None, problem
