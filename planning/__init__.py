"""Scenes, collision checking, grasp quality, the guided RRT-CONNECT and the experiments (paper VII-VIII)."""

__all__: list[str] = []
