"""Controllers: every one answers ``step(t, estimate, measurement) -> Action``."""
