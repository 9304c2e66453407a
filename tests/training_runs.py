"""A training run checked to resume from its checkpoint exactly, for any objective."""

from __future__ import annotations

from collections.abc import Callable

import torch

from models.maaip.trainer import Trainer


def parameters(trainer: Trainer) -> torch.Tensor:
    """The policy's, value's and discriminators' weights, flattened."""
    nets = [trainer.nets.policy, trainer.nets.value, *trainer.discriminators]
    return torch.cat([p.detach().reshape(-1) for n in nets for p in n.state_dict().values()])


def resumes_exactly(
    config,
    data,
    *,
    whole_done: Callable[[Trainer], None] = lambda _: None,
    resumed_done: Callable[[Trainer], None] = lambda _: None,
) -> list[dict]:
    """Three iterations of ``config`` on ``data`` straight through, against one iteration, a
    checkpoint and two more in a new trainer: the same weights and the same metrics but the
    wall-clock ones. Each finished trainer is handed to its callback before it closes. Returns
    the straight run's metrics."""
    whole = Trainer(config, data)
    try:
        expected = [whole.iterate() for _ in range(3)]
        final = parameters(whole)
        whole_done(whole)
    finally:
        whole.close()
    first = Trainer(config, data)
    try:
        first.iterate()
        blob = first.checkpoint()
    finally:
        first.close()
    resumed = Trainer(config, data)
    try:
        resumed.restore(blob)  # a new process would start exactly like this
        assert resumed.iteration == 1
        got = [resumed.iterate() for _ in range(2)]
        assert torch.equal(parameters(resumed), final)
        resumed_done(resumed)
    finally:
        resumed.close()
    timing = {k for k in expected[0] if k.endswith("_s") and not k.startswith("episode")}
    timing.add("env_steps_per_s")
    for want, have in zip(expected[1:], got, strict=True):
        assert {k: v for k, v in have.items() if k not in timing} == {
            k: v for k, v in want.items() if k not in timing
        }
    return expected
