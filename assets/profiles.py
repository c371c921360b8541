"""Run profiles: `demo` (minutes on 2 CPU cores, the default) and `paper` (the thesis's budgets).

Every training asset's Config has a `profile` field whose default comes from TRAFFICLEARN_PROFILE
(`make demo PROFILE=paper` sets it); fields left unset take that profile's value.
"""

import os

PROFILES = ("demo", "paper")


def default_profile() -> str:
    profile = os.environ.get("TRAFFICLEARN_PROFILE", "demo")
    if profile not in PROFILES:
        raise ValueError(f"TRAFFICLEARN_PROFILE={profile!r}: expected one of {', '.join(PROFILES)}")
    return profile


def resolve(config, defaults: dict[str, dict]) -> dict:
    """The config's values for the fields its profile has defaults for: the explicit value, else the profile's.

    `defaults`: profile -> {field: value}. One line, before any work, for an unknown profile, a negative count,
    fewer than one episode, or an empty list of seeds."""
    if config.profile not in defaults:
        raise ValueError(f"profile {config.profile!r}: expected one of {', '.join(defaults)}")
    assert set(defaults[config.profile]) <= set(type(config).model_fields), "a profile default names no config field"
    values = {k: v if (v := getattr(config, k)) is not None else d for k, d in defaults[config.profile].items()}
    if negative := {k: v for k, v in values.items() if isinstance(v, int) and not isinstance(v, bool) and v < 0}:
        raise ValueError(f"{', '.join(f'{k} {v}' for k, v in negative.items())}: expected counts >= 0")
    if values.get("episodes", 1) < 1:
        raise ValueError(f"episodes {values['episodes']}: expected at least 1")
    if values.get("seeds", [0]) == []:
        raise ValueError("seeds is empty: expected at least one seed")
    return values


def check_names(what: str, given, known) -> None:
    """One line, before any work, for names not among `known` or for none at all."""
    if (unknown := sorted(set(given) - set(known))) or not given:
        raise ValueError(f"{what} {unknown or 'none'}: expected one or more of {', '.join(known)}")
