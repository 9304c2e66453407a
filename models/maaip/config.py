"""The trainer's config (`TrainerConfig`): environment, networks, rewards, discriminators and
MAPPO, MAAIP §4.3-§4.5. The train stage's config (`tasks.train.config.TrainConfig`) is this and
how long a run lasts, when it checkpoints and where it starts from.

Numbers from the paper (Younes et al., "MAAIP: Multi-Agent Adversarial Interaction Priors",
SCA 2023) are marked as such; the rest are choices where the paper is silent (its
supplementary hyper-parameters are not available here), most following AMP (Peng et al.
2021) and MAPPO (Yu et al. 2021), which the paper builds on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

from models.arena.config import EnvConfig
from models.settings import setting
from models.tracking.config import TrackConfig

PRESETS: dict[str, tuple[int, ...]] = {
    # MAAIP §4.4: 3 hidden layers of 1024, 1024, 512 ReLU units.
    "paper": (1024, 1024, 512),
    # For training without a GPU: the fastest of the sizes `benchmarks/network_sizes.py`
    # measures (2,554 env steps/s end to end on 2 cores against 1,617 for 256,256,128).
    "cpu": (128, 128),
}
# Settings by name (`TrainerConfig.preset`): what each changes from the built-in defaults, which
# are the 'cpu' preset. 'paper' is MAAIP's thesis (Younes 2024, §3.3.1 and Table 3.1): 2,048
# arenas of two agents, 32 steps each, so 131,072 samples per iteration in 2 PPO minibatches of
# 6 epochs; episodes of 1,200 steps (40 s at 30 Hz); gradient penalty 5; discriminator batches
# of 4,096; action variance 0.0025 (std 0.05) on every joint; PPO clip 0.02; 1024-1024-512
# networks; on MuJoCo Warp. What it keeps: Adam's 2e-5, gamma 0.99, lambda 0.95, replay buffers
# of 100,000 and 30 Hz policies on 120 Hz physics (Isaac Gym's "60 Hz with 2 substeps") are
# already the defaults. docs/scaling.md says what each costs.
TRAIN_PRESETS: dict[str, dict[str, object]] = {
    "cpu": {},
    "paper": {
        "env.num_envs": 2048,
        "env.episode_s": 40.0,
        "env.stepping": "warp",
        "ppo.minibatch_size": 65536,
        "ppo.epochs": 6,
        "ppo.clip_coef": 0.02,
        "ppo.action_std": 0.05,
        "ppo.arm_action_std": 0.0,
        "discriminator.gp_weight": 5.0,
        "discriminator.samples_per_update": 4096,
        "network.preset": "paper",
    },
}
# What the tracker (`objective` 'track') changes from MAAIP's built-in defaults, in the settings
# left at them (as a preset does, applied before it): DeepMimic's discount, one action std on
# every joint, and the learning rate that reached the gate soonest (docs/train.md, "Time to
# the gate").
OBJECTIVE_DEFAULTS: dict[str, dict[str, object]] = {
    "maaip": {},
    "track": {
        "ppo.learning_rate": 3e-4,
        "ppo.action_std": 0.05,
        "ppo.arm_action_std": 0.0,
        "ppo.gamma": 0.95,
    },
}
DEVICES = ("auto", "cpu", "cuda")
CONTROL_TASKS = ("none", "damage_min", "damage_max", "heading")
DISCRIMINATOR_LOSSES = ("gail", "lsgan")
NUM_AGENTS = 2
HEADING_OBSERVATION_DIM = 2
OBJECTIVES = ("maaip", "track")


def _finite(value: float) -> bool:
    return math.isfinite(value)


@dataclass(frozen=True)
class NetworkConfig:
    """Sizes of the policy, the centralised value and the discriminators (MAAIP §4.4: all of a
    similar architecture, so all use the same hidden sizes here)."""

    preset: str = setting(
        "cpu",
        "Hidden layer sizes by name: 'paper' is 1024,1024,512 (MAAIP §4.4), 'cpu' is "
        "128,128 for training without a GPU (benchmarks/network_sizes.py).",
    )
    hidden: str = setting(
        "", "Comma-separated hidden layer sizes, e.g. '512,256'; overrides the preset if set."
    )
    observation_clip: float = setting(
        5.0, "Normalised observations are clipped to +-this many standard deviations."
    )
    mean_from_guard: bool = setting(
        True,
        "The policy's mean is its network's output plus each fighter's guard (its footage's "
        "median spine, neck and arms on bent knees that stand unaided, models.humanoid.stance), "
        "so an untrained policy holds its guard; false starts it at the rest pose, straight legs "
        "and arms hanging (MAAIP's policy outputs the targets directly). Starting straight-legged, "
        "no policy found bent knees, the first feature the priors told apart.",
    )

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(
                f"train.network.preset must be one of {sorted(PRESETS)}, got {self.preset!r}"
            )
        if self.hidden:
            self._parse_hidden()
        if not (self.observation_clip > 0 and _finite(self.observation_clip)):
            raise ValueError(
                f"train.network.observation_clip must be positive, got {self.observation_clip}"
            )

    def _parse_hidden(self) -> tuple[int, ...]:
        try:
            sizes = tuple(int(part) for part in self.hidden.split(","))
        except ValueError:
            sizes = ()
        if not sizes or min(sizes) < 1:
            raise ValueError(
                "train.network.hidden must be comma-separated positive integers such as "
                f"'1024,1024,512', got {self.hidden!r}"
            )
        return sizes

    @property
    def hidden_sizes(self) -> tuple[int, ...]:
        """The hidden layer sizes in use: ``hidden`` if set, else the preset's."""
        return self._parse_hidden() if self.hidden else PRESETS[self.preset]


@dataclass(frozen=True)
class RewardConfig:
    """How the motion, interaction and control rewards are weighted and scheduled (MAAIP eq 4,
    §4.5, §5.2-§5.4)."""

    w_motion: float = setting(
        0.2, "Weight w^M of the motion prior's reward (eq 4; 0.2 in MAAIP §5.2, 0.1 with a task)."
    )
    w_interaction: float = setting(
        0.8,
        "Weight w^I of the interaction prior's reward (eq 4; 0.8 in MAAIP §5.2, 0.4 with a task).",
    )
    w_control: float = setting(
        0.0,
        "Weight w^C of the control reward (0.5 in MAAIP §5.3-§5.4); 0 when control_task is 'none'.",
    )
    w_alive: float = setting(
        0.1,
        "Reward for every step lived, added to eq 4's sum (not in the paper). Measured on the "
        "demo dataset (18 min runs): with it at 0.1 episodes reached 7.4 s and falls 2.5 per "
        "minute at 1.7 M steps, without it 1.6 s; alone it buys standing, not style. 0 is off.",
    )
    control_task: str = setting(
        "none",
        "Control reward: 'none', 'damage_min' (eq 9), 'damage_max' (eq 10) or 'heading' (eq 11).",
    )
    interaction_start: int = setting(
        0,
        "Training iteration from which the interaction reward is on; before it only the motion "
        "reward is (MAAIP §4.5 reward scheduling, which gives no numbers).",
    )
    control_start: int = setting(
        500, "Training iteration from which the control reward is on (MAAIP §4.5 scheduling)."
    )
    renormalize_schedule: bool = setting(
        True,
        "While a reward is scheduled off, scale the active weights up so that they keep the sum "
        "of all three weights (so with 0.1/0.4/0.5 the middle phase is 0.2/0.8, the paper's "
        "imitation-only weights); false leaves them as they are.",
    )
    damage_scale: float = setting(
        0.01,
        "w in eqs 9-10 (1/N): a contact force of 1/damage_scale newtons on head, torso and "
        "pelvis gives exp(-1). The paper gives no value.",
    )
    heading_scale: float = setting(
        0.25, "w in eq 11 (s^2/m^2), on the squared shortfall of speed along the heading."
    )
    heading_speed: float = setting(
        1.0, "Target speed (m/s) along the target heading for the 'heading' task."
    )

    def __post_init__(self) -> None:
        weights = {
            "w_motion": self.w_motion,
            "w_interaction": self.w_interaction,
            "w_control": self.w_control,
        }
        for name, value in weights.items():
            if not (_finite(value) and value >= 0):
                raise ValueError(f"train.reward.{name} must be non-negative, got {value}")
        if not (_finite(self.w_alive) and self.w_alive >= 0):
            raise ValueError(f"train.reward.w_alive must be non-negative, got {self.w_alive}")
        if sum(weights.values()) <= 0:
            raise ValueError(
                "train.reward.w_motion + w_interaction + w_control must be positive; all three "
                "weights are 0, so the agents would get no reward"
            )
        if self.control_task not in CONTROL_TASKS:
            raise ValueError(
                f"train.reward.control_task must be one of {list(CONTROL_TASKS)}, got "
                f"{self.control_task!r}"
            )
        if self.control_task == "none" and self.w_control != 0:
            raise ValueError(
                f"train.reward.w_control must be 0 when train.reward.control_task is 'none', "
                f"got {self.w_control}"
            )
        if self.control_task != "none" and self.w_control <= 0:
            raise ValueError(
                f"train.reward.w_control must be positive when control_task is "
                f"{self.control_task!r}, got {self.w_control}"
            )
        for name in ("interaction_start", "control_start"):
            if getattr(self, name) < 0:
                raise ValueError(f"train.reward.{name} must be >= 0, got {getattr(self, name)}")
        first = self.w_motion
        first += self.w_interaction if self.interaction_start == 0 else 0.0
        first += self.w_control if self.control_start == 0 else 0.0
        if first <= 0:
            raise ValueError(
                "train.reward: every reward active at iteration 0 has weight 0 (w_motion is 0 "
                "and the others are scheduled later by interaction_start/control_start); give "
                "w_motion a positive weight or start another reward at 0"
            )
        for name in ("damage_scale", "heading_scale", "heading_speed"):
            value = getattr(self, name)
            if not (_finite(value) and value > 0):
                raise ValueError(f"train.reward.{name} must be positive, got {value}")

    @property
    def task_observation_dim(self) -> int:
        """Extra policy inputs for the control task: the target heading (x, y) in the agent's
        heading frame for 'heading' (MAAIP §5.4 conditions the policy on it), else 0."""
        return HEADING_OBSERVATION_DIM if self.control_task == "heading" else 0


@dataclass(frozen=True)
class DiscriminatorConfig:
    """How the motion prior D^M and the interaction priors D^I are trained (MAAIP eqs 7-8,
    12-13, Algorithm 1 lines 17-20)."""

    loss: str = setting(
        "gail",
        "Discriminator objective: 'gail' (cross-entropy, eqs 7-8, the paper's choice) or "
        "'lsgan' (least squares, eqs 12-13, worse for interaction in MAAIP §6.2).",
    )
    gp_weight: float = setting(
        10.0,
        "w_gp of the gradient penalty w_gp E||grad D||^2 on demonstration samples (eqs 7-8), "
        "taken on the logit with respect to the normalised input (AMP's 5 let the priors tell "
        "the policy apart 97-99 % of the time within 100 iterations on the demo).",
    )
    logit_reg: float = setting(
        0.05, "Weight of the squared output-layer weights added to the loss (as in AMP); 0 is off."
    )
    replay_size: int = setting(
        100_000,
        "Transitions kept in each discriminator's FIFO replay buffer of policy samples (§4.5).",
    )
    samples_per_update: int = setting(
        512, "K in Algorithm 1: demonstration and policy transitions per discriminator update."
    )
    updates_per_iteration: int = setting(
        1,
        "n in Algorithm 1: discriminator updates per training iteration. With 5 updates at a "
        "learning rate of 1e-4 the priors won at once on the demo's few hundred transitions "
        "(accuracy on the policy 0.97-0.99 by iteration 100, style rewards near 0.05, episodes "
        "of 1.1 s); with 1 at 2e-5 the episodes reached 5.5 s in 300 iterations (10 min pilots, "
        "one core each).",
    )
    learning_rate: float = setting(2e-5, "Adam learning rate of the discriminators.")
    input_noise: float = setting(
        0.0,
        "Standard deviation of Gaussian noise added to both sides' normalised inputs in each "
        "discriminator update (instance noise, so that no feature tells the footage apart "
        "exactly); accuracies are logged on the inputs as they are. 0 is off.",
    )
    max_reward: float = setting(
        9.21,
        "GAIL style reward -log(1 - D) is clipped to [0, max_reward]; 9.21 = -log(1e-4), i.e. "
        "D is capped at 0.9999.",
    )
    lsgan_reward_offset: float = setting(
        1.0, "u in eq 13, r = max(0, u - v (d - 1)^2); u = 1 and v = 0.25 bound r in [0, 1]."
    )
    lsgan_reward_scale: float = setting(0.25, "v in eq 13.")

    def __post_init__(self) -> None:
        if self.loss not in DISCRIMINATOR_LOSSES:
            raise ValueError(
                f"train.discriminator.loss must be one of {list(DISCRIMINATOR_LOSSES)}, got "
                f"{self.loss!r}"
            )
        for name in ("gp_weight", "logit_reg", "input_noise"):
            value = getattr(self, name)
            if not (_finite(value) and value >= 0):
                raise ValueError(f"train.discriminator.{name} must be non-negative, got {value}")
        for name in ("replay_size", "samples_per_update", "updates_per_iteration"):
            if getattr(self, name) < 1:
                raise ValueError(
                    f"train.discriminator.{name} must be at least 1, got {getattr(self, name)}"
                )
        for name in ("learning_rate", "max_reward", "lsgan_reward_offset", "lsgan_reward_scale"):
            value = getattr(self, name)
            if not (_finite(value) and value > 0):
                raise ValueError(f"train.discriminator.{name} must be positive, got {value}")


@dataclass(frozen=True)
class PPOConfig:
    """MAPPO (MAAIP §4.5, Algorithm 1 line 21): GAE(lambda) advantages, TD(lambda) value
    targets, clipped surrogate, a Gaussian policy with a fixed standard deviation (§4.4)."""

    gamma: float = setting(0.99, "Discount factor.")
    gae_lambda: float = setting(0.95, "lambda of GAE(lambda) and TD(lambda).")
    clip_coef: float = setting(0.2, "PPO ratio clip epsilon (MAPPO recommends <= 0.2).")
    epochs: int = setting(5, "Passes over each batch of samples (MAPPO: 5 for hard tasks).")
    minibatch_size: int = setting(1024, "Samples per PPO gradient step.")
    learning_rate: float = setting(
        2e-5,
        "Adam learning rate of the policy and the value (AMP's 2e-5: with the fixed, small "
        "action_std, 1e-4 moved the policy past the clip range, KL 0.06-0.15 per iteration).",
    )
    action_std: float = setting(
        0.02,
        "Fixed standard deviation of every action dimension (MAAIP §4.4 fixes the covariance), "
        "in the action's units (radians of PD targets). AMP's 0.055 = exp(-2.9) fells a body "
        "holding its rest pose in about 2 s; with 0.02 it stands 30 s (tests/test_standing.py).",
    )
    arm_action_std: float = setting(
        0.1,
        "Exploration std of the shoulders' and elbows' actions instead of action_std (radians): "
        "arm noise costs no balance, where leg noise fells the body, and a fighter must move its "
        "arms far from its guard to punch (15 min pilots on the demo: falls per minute as with "
        "0.02). 0 uses action_std.",
    )
    value_coef: float = setting(0.5, "Weight of the value loss in the PPO loss.")
    horizon: int = setting(32, "T: steps collected per environment per iteration.")
    max_grad_norm: float = setting(1.0, "Gradients are clipped to this global norm.")
    normalize_advantages: bool = setting(
        True, "Advantages are standardised per minibatch (MAPPO does)."
    )

    def __post_init__(self) -> None:
        if not 0 < self.gamma <= 1:
            raise ValueError(f"train.ppo.gamma must be in (0, 1], got {self.gamma}")
        if not 0 <= self.gae_lambda <= 1:
            raise ValueError(f"train.ppo.gae_lambda must be in [0, 1], got {self.gae_lambda}")
        if not (_finite(self.arm_action_std) and self.arm_action_std >= 0):
            raise ValueError(
                f"train.ppo.arm_action_std must be non-negative, got {self.arm_action_std}"
            )
        for name in ("clip_coef", "learning_rate", "action_std", "max_grad_norm"):
            value = getattr(self, name)
            if not (_finite(value) and value > 0):
                raise ValueError(f"train.ppo.{name} must be positive, got {value}")
        if not (_finite(self.value_coef) and self.value_coef >= 0):
            raise ValueError(f"train.ppo.value_coef must be non-negative, got {self.value_coef}")
        for name in ("epochs", "minibatch_size", "horizon"):
            if getattr(self, name) < 1:
                raise ValueError(f"train.ppo.{name} must be at least 1, got {getattr(self, name)}")

    def batch_size(self, num_envs: int) -> int:
        """Samples per iteration: every step of every environment, for both agents."""
        return num_envs * self.horizon * NUM_AGENTS


@dataclass(frozen=True)
class DistillConfig:
    """MAAIP from the tracker (`models.maaip.distill`): before its first iteration a MAAIP run
    fits its policy to the actions of the dataset's newest tracker run on the footage (DART's
    noisy teacher, then DAgger's own rollouts), and fine-tunes from there."""

    from_tracker: bool = setting(
        False,
        "Start from the dataset's newest finished tracker run (`train.objective` 'track' on the "
        "same dataset), distilled into this run's policy; the run's key names that tracker run. "
        "Instead of `warm_start`.",
    )
    rounds: int = setting(
        4,
        "Rounds of collection and fitting: the first acts on the tracker's actions plus noise, "
        "the others on the distilled policy's own (DAgger); each refits on every label so far.",
    )
    steps: int = setting(60, "Policy steps per round in each of `env.num_envs` arenas.")
    noise: float = setting(
        0.05, "Std (rad) of the noise on the tracker's actions in the first round (DART)."
    )
    epochs: int = setting(10, "Passes over the labels at each fit.")
    minibatch_size: int = setting(512, "Samples per gradient step of a fit.")
    learning_rate: float = setting(1e-3, "Adam learning rate of the fits.")

    def __post_init__(self) -> None:
        for name in ("rounds", "steps", "epochs", "minibatch_size"):
            if getattr(self, name) < 1:
                raise ValueError(
                    f"train.distill.{name} must be at least 1, got {getattr(self, name)}"
                )
        if not (_finite(self.noise) and self.noise >= 0):
            raise ValueError(f"train.distill.noise must be non-negative, got {self.noise}")
        if not (_finite(self.learning_rate) and self.learning_rate > 0):
            raise ValueError(
                f"train.distill.learning_rate must be positive, got {self.learning_rate}"
            )


@dataclass(frozen=True)
class TrainerConfig:
    """What the trainer (`models.maaip.trainer.Trainer`) is built from: objective, seed, device
    and the parts above."""

    objective: str = setting(
        "maaip",
        "What the policy learns: 'maaip' (adversarial motion and interaction priors, MAAIP) or "
        "'track' (follow reference clips with DeepMimic's reward, the `track` section; no "
        "discriminators). A tracker takes its own defaults where these settings are left at "
        "theirs: ppo.learning_rate 3e-4, ppo.gamma 0.95, ppo.action_std 0.05 and "
        "ppo.arm_action_std 0 (OBJECTIVE_DEFAULTS in models/maaip/config.py).",
    )
    preset: str = setting(
        "cpu",
        "Settings by name: 'cpu' (the defaults: 64 arenas, 128-128 networks, 4,096 samples per "
        "iteration, for this kind of machine) or 'paper' (MAAIP's thesis, Table 3.1: 2,048 "
        "arenas on MuJoCo Warp, 1024-1024-512 networks, 131,072 samples per iteration, for a "
        "GPU; TRAIN_PRESETS in models/maaip/config.py, costs in docs/scaling.md). A preset "
        "changes only the settings left at their built-in defaults: a value given that differs "
        "from the default wins, one equal to it cannot be told from ringside.toml's own.",
    )
    seed: int = setting(0, "Seeds network initialisation, sampling and the environments.")
    device: str = setting(
        "auto",
        "Where the networks train: 'auto' (CUDA when torch sees a GPU, else the CPU), 'cpu' or "
        "'cuda'. The physics runs there too with train.env.stepping 'warp', else on the CPU.",
    )
    network: NetworkConfig = field(default_factory=NetworkConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    discriminator: DiscriminatorConfig = field(default_factory=DiscriminatorConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    env: EnvConfig = field(default_factory=EnvConfig)
    track: TrackConfig = field(default_factory=TrackConfig)
    distill: DistillConfig = field(default_factory=DistillConfig)

    def __post_init__(self) -> None:
        if self.preset not in TRAIN_PRESETS:
            raise ValueError(
                f"train.preset must be one of {list(TRAIN_PRESETS)}, got {self.preset!r}"
            )
        if self.objective not in OBJECTIVES:
            raise ValueError(
                f"train.objective must be one of {list(OBJECTIVES)}, got {self.objective!r}"
            )
        if self.objective == "track" and self.reward.control_task != "none":
            raise ValueError(
                "train.reward.control_task must be 'none' with train.objective 'track' (the "
                f"tracker takes no control task), got {self.reward.control_task!r}"
            )
        if self.distill.from_tracker and (
            self.objective != "maaip" or self.reward.control_task == "heading"
        ):
            raise ValueError(
                "train.distill.from_tracker needs train.objective 'maaip' without the heading "
                "task (the tracker's actions are the fighters' own, with no target to head for)"
            )
        if self.device not in DEVICES:
            raise ValueError(f"train.device must be one of {list(DEVICES)}, got {self.device!r}")
        batch = self.ppo.batch_size(self.env.num_envs)
        if self.ppo.minibatch_size > batch:
            raise ValueError(
                f"train.ppo.minibatch_size ({self.ppo.minibatch_size}) must not exceed the "
                f"batch, env.num_envs x ppo.horizon x {NUM_AGENTS} agents = {batch}"
            )

    def with_preset(self) -> TrainerConfig:
        """This config with its objective's values (`OBJECTIVE_DEFAULTS`), then its preset's
        (`TRAIN_PRESETS`), in the settings left at their built-in defaults: a value given that
        differs from the default wins. Settings read from ringside.toml or flags get it as they
        are built (`tasks.config.build`); a config built in code and then changed
        (`dataclasses.replace`) keeps what it was given."""
        config = self
        for changes in (OBJECTIVE_DEFAULTS[self.objective], TRAIN_PRESETS[self.preset]):
            for name, value in changes.items():
                section, leaf = name.split(".")
                part = getattr(config, section)
                default = next(f.default for f in fields(part) if f.name == leaf)
                if getattr(part, leaf) == default:
                    config = replace(config, **{section: replace(part, **{leaf: value})})
        return config
