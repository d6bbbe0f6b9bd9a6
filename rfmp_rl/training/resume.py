"""Continuing a run: find its ``last.pt``, rebuild its configuration, refuse what cannot continue.

``resume=<run folder or last.pt>`` continues the run in place. The configuration is the run's
own (``config.yaml`` beside ``last.pt``) with the command line's explicit overrides on top, so
``python recipes/pusht/train.py resume=runs/pusht/x`` needs nothing else, and
``resume=runs/pusht/x train.steps=20000`` extends it. An override that changes what the run
*is* (the recipe's fixed fields: algorithm, manifold, horizons, architecture) is refused before
anything in the run folder is touched.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from rfmp_rl.checkpoint import read_checkpoint

__all__ = ["check_resumable", "resume_checkpoint", "resume_config"]

#: ModelConfig fields a loss fills in at construction: a freshly built model has them unset.
RECORDED_BY_THE_LOSS = ("tau_max",)


def check_resumable(payload: dict, path, recipe: str, model_config: dict | None = None) -> None:
    """Refuse a checkpoint that cannot continue a run of ``recipe`` (no training state: best.pt
    or an older checkpoint; another recipe's run; with ``model_config``, a different model),
    naming what differs."""
    state = payload.get("training_state")
    if state is None:
        raise ValueError(f"resume={path}: this checkpoint holds no training state (best.pt and "
                         "checkpoints of older versions cannot be resumed; use the run's last.pt)")
    if state.get("recipe") != recipe:
        raise ValueError(f"resume={path}: a run of recipe {state.get('recipe')!r}, not "
                         f"{recipe!r}")
    if model_config is None:
        return
    stored = payload["model_config"]
    # tau_max is written by the SRFMP loss when it is built (after this check), which also
    # refuses a run whose recorded range differs from the one it trains
    differ = sorted(k for k in set(stored) | set(model_config)
                    if stored.get(k) != model_config.get(k)
                    and not (k in RECORDED_BY_THE_LOSS and model_config.get(k) is None))
    if differ:
        details = ", ".join(f"{k}: run {stored.get(k)!r} vs now {model_config.get(k)!r}"
                            for k in differ)
        raise ValueError(f"resume={path}: the model differs from the run's ({details}); resume "
                         "with the run's settings or start a new run")


def resume_checkpoint(path: str | Path, recipe: str) -> Path:
    """The ``last.pt`` of ``path`` (a run folder or the file itself), checked to be a resumable
    run of ``recipe``; raises a `ValueError` naming the path otherwise."""
    path = Path(path)
    last = path / "last.pt" if path.is_dir() else path
    if not last.is_file():
        where = f"the folder {path} has no last.pt" if path.is_dir() else f"{path} does not exist"
        raise ValueError(f"resume={path}: {where} (give a run folder or its last.pt)")
    check_resumable(read_checkpoint(last), path, recipe)
    if not (last.parent / "config.yaml").is_file():
        raise ValueError(f"resume={path}: no config.yaml beside {last.name}")
    return last


def _get(cfg: DictConfig, dotted: str):
    return OmegaConf.select(cfg, dotted, default=None)


def resume_config(cfg: DictConfig, last: Path, fixed: Sequence[str],
                  overrides: Sequence[str] | None = None) -> DictConfig:
    """The configuration of the resumed run.

    Args:
        cfg: the command line's configuration.
        last: the run's ``last.pt`` (`resume_checkpoint`).
        fixed: dotted fields that define the run (e.g. ``algo``, ``space``, ``horizon``).
        overrides: the command line's explicit overrides (hydra's ``key=value`` strings). With
            them the run's stored configuration is used and only these are applied on top; with
            None, ``cfg`` is taken as the full configuration.

    Raises:
        ValueError: naming every fixed field whose value would change.
    """
    stored = OmegaConf.load(last.parent / "config.yaml")
    if overrides is None:
        merged = OmegaConf.merge(stored, cfg)
    else:
        given = [o for o in overrides if not o.lstrip("+~").startswith("resume=")]
        removed = [o for o in given if o.startswith("~")]
        if removed:
            raise ValueError(f"resume={last.parent}: {removed[0]!r} removes a setting, which a "
                             "resumed run cannot do; override its value instead")
        # the recipe's current defaults (settings added since the run), the run's own
        # configuration, then what this command line sets
        merged = OmegaConf.merge(cfg, stored,
                                 OmegaConf.from_dotlist([o.lstrip("+") for o in given]))
    merged.resume = str(last.parent)
    merged.out_dir = str(last.parent)
    changed = [k for k in fixed if _get(stored, k) != _get(merged, k)]
    if changed:
        details = ", ".join(f"{k}={_get(merged, k)!r} (the run has {_get(stored, k)!r})"
                            for k in changed)
        raise ValueError(f"resume={last.parent}: {details}; these settings define the run and "
                         "cannot change when it is resumed (start a new run instead)")
    return merged
