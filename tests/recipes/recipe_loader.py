"""Import a recipe's scripts and compose its hydra config (shared by the recipe smoke tests)."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # `recipes.common` of this checkout, as the scripts import it
    sys.path.insert(0, str(ROOT))


# Diffusion Policy's Push-T demonstrations: the Push-T recipe tests run on the real zarr.
PUSHT = Path(os.environ.get("RFMP_PUSHT_ZARR", ROOT.parent / "shared/data/pusht/"
                            "pusht_cchi_v7_replay.zarr"))


def pusht_marks() -> list:
    """The marks of a Push-T recipe test module: slow, and skipped without the zarr."""
    import pytest

    return [
        pytest.mark.slow,
        pytest.mark.skipif(not PUSHT.exists(), reason=f"Push-T zarr not found at {PUSHT}: place "
                           "Diffusion Policy's pusht_cchi_v7_replay.zarr there or set "
                           "RFMP_PUSHT_ZARR"),
    ]


# A Push-T recipe run of a few steps on three episodes (the smoke tests' overrides).
PUSHT_TINY = [
    "train.steps=2", "train.val_every=1", "train.val_batches=1", "train.batch_size=4",
    "train.log_every=1", "optim.warmup_steps=1", "data.max_episodes=3", "data.val_episodes=2",
    "eval.seeds=2", "eval.nfes=[1]", "eval.t_ends=[1.0]", "eval.max_steps=12",
    "eval.time_table=[]", "model.down_dims=[16,32]", f"data.path={PUSHT}", "threads=1",
]


#: the recipes' own modules, imported by bare name by their scripts (one per recipe folder)
LOCAL_MODULES = ("utils", "experts")


def load_recipe(name: str, extra: tuple[str, ...] = ()):
    """Import recipes/<name>/{utils,train,eval}.py and the ``extra`` scripts (e.g.
    ``("eval_onnx",)``; the scripts import their local `utils`, and `experts` when they write
    demonstrations); yields ``{"utils": ..., "train": ..., "eval": ..., <extra>: ...}`` and
    restores ``sys.path`` and those two modules after (each recipe has its own)."""
    folder = ROOT / "recipes" / name
    saved = {local: sys.modules.pop(local, None) for local in LOCAL_MODULES}
    sys.path.insert(0, str(folder))
    try:
        mods = {}
        for part in ("utils", "train", "eval", *extra):
            spec = importlib.util.spec_from_file_location(
                part if part == "utils" else f"{name}_{part}", folder / f"{part}.py"
            )
            module = importlib.util.module_from_spec(spec)
            if part == "utils":
                sys.modules["utils"] = module
            spec.loader.exec_module(module)
            mods[part] = module
        yield mods
    finally:
        sys.path.remove(str(folder))
        for local, module in saved.items():
            sys.modules.pop(local, None)
            if module is not None:
                sys.modules[local] = module


def compose(name: str, overrides: list[str]):
    """The recipe's hydra config with ``overrides``."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "recipes" / name), version_base="1.3"):
        return hydra_compose("config", overrides=overrides)


def load_script(recipe: str, script: str):
    """Import one stand-alone script, recipes/<recipe>/<script>.py, as a module."""
    spec = importlib.util.spec_from_file_location(
        f"{recipe}_{script}", ROOT / "recipes" / recipe / f"{script}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # under its own name (dataclasses look it up)
    spec.loader.exec_module(module)
    return module
