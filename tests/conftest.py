"""Shared pytest settings: deterministic hypothesis profile so CI runs are reproducible."""
from hypothesis import HealthCheck, settings

settings.register_profile(
    "cobotlab", max_examples=200, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("cobotlab")
