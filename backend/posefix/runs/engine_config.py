"""The engine configuration a server runs with: the settings' config file and a run's edit rules."""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from typing import Any

from posefix.config import Settings
from posefix.core.rules import EditRules
from posefix.engine import CorrectionConfig


@lru_cache(maxsize=4)
def _load_config(path: str | None) -> CorrectionConfig:
    return CorrectionConfig.load(path) if path else CorrectionConfig()


def engine_config(settings: Settings, rules: dict[str, Any] | None = None) -> CorrectionConfig:
    cfg = _load_config(str(settings.engine_config) if settings.engine_config else None)
    if rules is not None:
        cfg = dataclasses.replace(cfg, rules=EditRules.from_json(rules))
    return cfg


def default_rules(settings: Settings) -> dict[str, Any]:
    return engine_config(settings).rules.to_json()
