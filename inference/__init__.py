"""The variation model: a GTSAM factor graph over the object pose and the hand trajectory (paper V-VII)."""

__all__: list[str] = []
