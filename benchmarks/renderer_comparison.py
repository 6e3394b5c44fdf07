"""TinyRenderer against EGL: the same start state rendered by both, side by side, and how far apart they are.

Prints, per scene and camera, the mean absolute difference in grey levels (0-255) between the two renderers,
and writes a PNG of both cameras under both renderers (``--output``).

Usage::

    python benchmarks/renderer_comparison.py --output docs/images/renderers.png [--assets-dir CALVIN_ENV]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lerobot_subgoalvla.envs.calvin.evaluation.chains import (
    EVAL_ROBOT_OBS,
    generate_chains,
    scene_obs_for_state,
)
from lerobot_subgoalvla.envs.calvin.protocol import RENDERERS
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation


def render(scene: str, assets_dir: Path | None, renderer: str) -> dict[str, np.ndarray]:
    """Both cameras at the start of CALVIN's chain 0."""
    chain = generate_chains(1)[0]
    with CalvinSimulation(scene, assets_dir=assets_dir, renderer=renderer) as sim:
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=scene_obs_for_state(chain.initial_state))
        return sim.render_cameras()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=Path("renderers.png"), help="PNG to write")
    parser.add_argument("--assets-dir", type=Path, default=os.environ.get("CALVIN_ENV_ASSETS"),
                        help="calvin_env clone: adds scene calvin_D")  # fmt: skip
    args = parser.parse_args()
    scenes = ["procedural"] + (["calvin_D"] if args.assets_dir else [])
    images = {(s, r): render(s, args.assets_dir, r) for s in scenes for r in RENDERERS}
    print("| scene | camera | mean abs difference tiny vs egl (grey levels) |")
    print("| --- | --- | --- |")
    for scene in scenes:
        for camera in ("static", "gripper"):
            a, b = (images[(scene, r)][camera].astype(float) for r in RENDERERS)
            print(f"| {scene} | {camera} | {np.abs(a - b).mean():.1f} |")
    fig = Figure(figsize=(3 * 2 * len(RENDERERS), 3 * len(scenes)), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(scenes), 2 * len(RENDERERS), squeeze=False)
    for row, scene in enumerate(scenes):
        for col, (camera, renderer) in enumerate((c, r) for c in ("static", "gripper") for r in RENDERERS):
            axes[row][col].imshow(images[(scene, renderer)][camera])
            axes[row][col].set_title(f"{scene} {camera}: {renderer}", fontsize=9)
            axes[row][col].axis("off")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
