"""Print parameter counts of the policy networks for the paper's task configurations.

    bash recipes/venv.sh python recipes/benchmarks/param_counts.py [--preset paper]

The vector field (VF) count is the UNet (with SRFMP's tau head); the ResNet count is one camera
encoder's convolutional trunk, as in the paper's hyperparameter table.
"""

from __future__ import annotations

import argparse

from configs import PAPER_COUNTS, task_config

from rfmp_rl.modules import build_model


def count(module) -> int:
    return sum(p.numel() for p in module.parameters())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper", help="small | paper | paper_real")
    args = parser.parse_args()
    header = "| task | RFMP VF | SRFMP VF | DDIM VF | ResNet/camera | paper RFMP / SRFMP / ResNet |"
    print(f"UNet preset: {args.preset}\n")
    print(header)
    print("|---|---|---|---|---|---|")
    for task in ("pusht_state", "pusht_image", "robomimic_state", "robomimic_image"):
        counts = {}
        resnet = None
        for algorithm in ("rfmp", "srfmp", "ddim"):
            model = build_model(task_config(task, algorithm, args.preset))
            counts[algorithm] = count(model.network)
            vision = model.obs_encoder.vision
            if vision is not None:
                resnet = count(next(iter(vision.encoders.values())).trunk)
        paper = " / ".join("-" if v is None else f"{v:.3g}" for v in PAPER_COUNTS[task])
        print(
            f"| {task} | {counts['rfmp']:,} | {counts['srfmp']:,} | {counts['ddim']:,} | "
            f"{'-' if resnet is None else f'{resnet:,}'} | {paper} |"
        )


if __name__ == "__main__":
    main()
