"""The shipped demonstrations (``<object>.npz``, format in ``README.md``) and their generator
(:mod:`assets.demonstrations.generate`, a data build script run by ``pbdgrasp demo generate``); their
names: :func:`assets.demonstration_names`."""
