"""Section VII of the paper: scenes, the pybullet world, collision checking, grasp quality, the guided
RRT-CONNECT and its peers, and the planner registry behind :class:`~planning.grasp_planner.GraspPlanner`."""

__all__: list[str] = []
