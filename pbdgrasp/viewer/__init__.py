"""The 3-D viewer (``pbdgrasp view``): a viser server showing a scene, strategies and planned trials.

:mod:`.meshes` makes the triangle meshes and poses (numpy, trimesh), :mod:`.app` serves them
(:class:`~pbdgrasp.viewer.app.StrategyViewer`), :mod:`.browser` takes screenshots in headless Chromium.
This package imports nothing heavy itself, so the command line can read :data:`LAYERS` cheaply.
"""

LAYERS = ("scene", "hand", "marginals", "draws", "path", "grasp")
"""The top scene nodes of the viewer, each shown or hidden as a whole."""
