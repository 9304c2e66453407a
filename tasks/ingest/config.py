"""The ingest stage's config and the analyst's declaration of who the adversary is."""

from __future__ import annotations

import re
from dataclasses import dataclass

from models.settings import setting
from tasks.errors import BadInput

# Trunk and glove colours analysts name, as RGB; anything else is given as #rrggbb.
NAMED_COLOURS: dict[str, tuple[int, int, int]] = {
    "black": (0, 0, 0),
    "white": (255, 255, 255),
    "grey": (128, 128, 128),
    "red": (200, 30, 30),
    "blue": (30, 60, 200),
    "navy": (20, 30, 100),
    "green": (30, 150, 60),
    "yellow": (240, 210, 40),
    "gold": (210, 170, 50),
    "orange": (240, 130, 30),
    "purple": (120, 40, 150),
    "pink": (240, 120, 170),
    "brown": (110, 70, 40),
}


@dataclass(frozen=True)
class IngestConfig:
    """How videos are probed, cut into shots and planned into chunks."""

    cut_threshold: float = setting(
        0.45,
        "Bhattacharyya distance (0-1) between the hue-saturation histograms of consecutive "
        "frames above which a shot cut is declared.",
    )
    structure_threshold: float = setting(
        0.2,
        "Structure distance (0-1: one minus the correlation of consecutive frames' grey "
        "thumbnails, halved) above which a shot cut is declared too: a cut to a mirrored or "
        "re-framed view keeps the colours (histogram distance 0.02-0.06 on the sample's views) "
        "but not the picture (0.21-0.41 mirrored, 0.36-0.52 a 2x crop; consecutive frames of the "
        "sample 0.004 at most, a pan of 5 % of the frame width per frame 0.12; "
        "benchmarks/cut_distances.py). A whip pan faster than about 9 % of the width per frame "
        "reads as a cut.",
    )
    flat_contrast: float = setting(
        10.0,
        "A frame whose contrast (standard deviation of its grey thumbnail, in grey levels 0-255) "
        "is below this is flat: its layout is not compared (a flat frame's thumbnail is all "
        "zeros), only its colours. The sample's views have 35-46.",
    )
    dark_level: float = setting(
        48.0,
        "A flat frame darker than this mean grey level (0-255) is blank, the middle of a fade to "
        "black: not compared at all (a dark pixel's hue is noise; faded to black a tenth at a "
        "time, the sample's consecutive frames' colours differ by 0.27 at contrast 8 and by "
        "0.47, a cut, at 4: benchmarks/cut_distances.py). The next frame that is not blank is "
        "compared with the last that was not, so a fade to black and back within a shot is no "
        "cut and a fade from one shot into another is one, at the new shot's first frame that "
        "is not blank.",
    )
    min_shot_frames: int = setting(
        12, "A cut closer than this many frames to the previous one is ignored (flashes, strobes)."
    )
    histogram_width: int = setting(
        160, "Frames are shrunk to this width (pixels) before their histograms are taken."
    )
    chunk_frames: int = setting(
        300, "Frames per chunk that later stages process as one task; chunks never cross a cut."
    )
    truncation_tolerance: float = setting(
        0.02,
        "Share of the frames the container declares that may fail to decode before the file is "
        "called truncated.",
    )
    frame_interval_spread: float = setting(
        0.25,
        "A video whose frame intervals (the container's timestamps) spread more than this share "
        "around their median (5th to 95th percentile) has a variable frame rate: it is re-timed "
        "onto a constant grid at its fastest rate (each grid frame shows the frame shown at that "
        "moment), so that every later stage's times are real. Phones' small jitter stays under it.",
    )
    thumbnail_width: int = setting(320, "Width (pixels) of the still stored for each shot.")
    min_frames: int = setting(
        10,
        "A video with fewer decodable frames is refused at ingest: the lift needs a fighter in "
        "10 frames (lift.min_frames) and the dataset a clip of 1 s.",
    )

    def __post_init__(self) -> None:
        for name in ("flat_contrast", "dark_level"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"ingest.{name} must be at least 0, got {getattr(self, name)}")
        if not self.frame_interval_spread > 0.0:
            raise ValueError(
                f"ingest.frame_interval_spread must be positive, got {self.frame_interval_spread}"
            )
        for name in ("cut_threshold", "structure_threshold"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"ingest.{name} must be in (0, 1], got {getattr(self, name)}")
        for name in (
            "min_shot_frames",
            "histogram_width",
            "chunk_frames",
            "thumbnail_width",
            "min_frames",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"ingest.{name} must be at least 1, got {getattr(self, name)}")
        if not 0.0 <= self.truncation_tolerance < 1.0:
            raise ValueError(
                f"ingest.truncation_tolerance must be in [0, 1), got {self.truncation_tolerance}"
            )


@dataclass(frozen=True)
class AdversaryDeclaration:
    """Who the adversary is in a video, as the analyst says it.

    ``colour`` is the adversary's trunk or glove colour, normalised to ``#rrggbb``; ``None`` leaves
    the choice of track to the analyst's pick later.
    """

    name: str
    colour: str | None = None
    notes: str | None = None


def parse_colour(text: str) -> str:
    """``text`` (a colour name from NAMED_COLOURS or ``#rrggbb``) as ``#rrggbb``."""
    value = text.strip().lower()
    if value == "gray":
        value = "grey"
    if value in NAMED_COLOURS:
        r, g, b = NAMED_COLOURS[value]
        return f"#{r:02x}{g:02x}{b:02x}"
    if re.fullmatch(r"#[0-9a-f]{6}", value):
        return value
    raise BadInput(
        "--adversary-colour",
        f"unknown colour {text!r}; use #rrggbb or one of {', '.join(sorted(NAMED_COLOURS))}",
    )


def declare(name: str, colour: str | None = None, notes: str | None = None) -> AdversaryDeclaration:
    """A checked declaration: the name is required, the colour is normalised."""
    if not name or not name.strip():
        raise BadInput("--adversary", "the adversary needs a name")
    return AdversaryDeclaration(
        name=name.strip(),
        colour=parse_colour(colour) if colour else None,
        notes=notes.strip() if notes else None,
    )
