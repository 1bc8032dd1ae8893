"""diffstir: identify a fluid by stirring it.

A differentiable MLS-MPM stirring simulator in PyTorch, non-Newtonian rheology laws as
``nn.Module``s, and the tools around them. All quantities are SI (m, s, kg, N, Pa, Pa·s).
"""

__version__ = "0.1.0"
