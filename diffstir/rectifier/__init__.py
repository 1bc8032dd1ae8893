"""The learned sim-to-real rectifier: a small MLP that maps (mean stirring speed, preliminary viscosity) to a refined
viscosity, trained on virtual-lab pairs (``pairs``) with Lightning (``training``); ``Rectifier`` is the plain
torch module and ``refine`` applies a trained one with a check of its training range. See docs/rectifier.md."""
