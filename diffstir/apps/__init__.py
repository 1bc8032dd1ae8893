"""Command-line applications; the only modules that import Hydra."""
