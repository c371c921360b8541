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
