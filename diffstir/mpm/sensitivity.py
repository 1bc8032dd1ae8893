"""Forward-mode sensitivities of the force on the rod: the Jacobian d F(t) / d p for a handful of parameters p.

Reverse mode (``result.force.abs().mean().backward()``) gives the gradient of one scalar per backward pass; a
Gauss-Newton step, a sensitivity study or an experiment design needs the whole Jacobian of the force over time,
d F(t_i) / d p_j for every step i and a few parameters j. Forward mode gives one column per rollout, carrying dual
numbers (``torch.autograd.forward_ad``) through the steps with the parameters swapped in by
``torch.func.functional_call``; it keeps no tape and no checkpoints, so its memory does not grow with the horizon.
(``torch.func.jvp`` itself cannot be used: the rollout checks every step's state for finiteness, a data-dependent
branch that its tracing refuses.) What it costs against a plain rollout, a reverse-mode gradient and finite
differences is measured by ``scripts/benchmark_sensitivities.py`` (``docs/benchmarks.md``).

    sens = force_sensitivities(sim, trajectory)                # every parameter of the simulator
    sens.force_jacobian[:, 0, j]                               # d F_x(t) / d p_j, p_j = sens.names[j]

A parameter of a rheology law is an unconstrained ``raw`` tensor mapped into its bounds
(``diffstir.rheology.BoundedParameter``); its column is reported per unit of the physical value
(d F / d value = (d F / d raw) / (d value / d raw)), named after the law's parameter with its SI unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.autograd.forward_ad as fwAD
from torch import Tensor, nn
from torch.func import functional_call

from ..rheology.parameters import BoundedParameter
from ..trajectory import Trajectory
from .state import State


@dataclass
class Sensitivities:
    """A rollout's force and torque with their derivatives with respect to k parameters.

    Attributes:
        times: mid-step times [s], (T,).
        force: the fluid's force on the rod [N] (2-D: [N/m]), (T, d).
        torque: its torque about the rod's axis [N·m] (2-D: [N]), (T,).
        names: what each column differentiates by: a law parameter as ``"<name> [<SI unit>]"`` (``"eta0 [Pa·s]"``),
            any other parameter by its name in ``simulator.named_parameters()``, (k,).
        force_jacobian: d force / d p [force unit per unit of p], (T, d, k).
        torque_jacobian: d torque / d p, (T, k).
    """

    times: Tensor
    force: Tensor
    torque: Tensor
    names: list[str]
    force_jacobian: Tensor
    torque_jacobian: Tensor


def force_sensitivities(simulator: nn.Module, trajectory: Trajectory, parameters: list[str] | None = None, *,
                        initial: State | None = None) -> Sensitivities:
    """d force(t) / d p by forward-mode differentiation, one rollout per scalar parameter.

    Args:
        simulator: a ``StirringSimulator``.
        trajectory: the rod's path.
        parameters: names from ``simulator.named_parameters()`` (default: all); a tensor parameter contributes one
            column per element.
        initial: the fluid's starting state (default: the settled fluid, as ``simulator(trajectory)``).
    """
    named = dict(simulator.named_parameters())
    wanted = list(named) if parameters is None else list(parameters)
    unknown = [name for name in wanted if name not in named]
    if unknown:
        raise ValueError(f"force_sensitivities: unknown parameters {unknown}; the simulator has {list(named)}")
    owners = {f"{path}.raw": module for path, module in simulator.named_modules()
              if isinstance(module, BoundedParameter)}
    primal = {name: p.detach() for name, p in named.items()}
    result, names, force_columns, torque_columns = None, [], [], []
    for name in wanted:
        value = primal[name]
        for index in range(value.numel()):
            tangent = torch.zeros_like(value).reshape(-1)
            tangent[index] = 1.0
            with fwAD.dual_level(), torch.no_grad():
                inputs = dict(primal)
                inputs[name] = fwAD.make_dual(value, tangent.reshape(value.shape))
                out = functional_call(simulator, inputs, (trajectory,), {"initial": initial})
                force, d_force = fwAD.unpack_dual(out.force)
                torque, d_torque = fwAD.unpack_dual(out.torque)
                per_raw = _value_per_raw(owners.get(name), inputs[name])
            if result is None:
                result = out.times, force, torque
            d_force = torch.zeros_like(force) if d_force is None else d_force
            d_torque = torch.zeros_like(torque) if d_torque is None else d_torque
            force_columns.append(d_force / per_raw)
            torque_columns.append(d_torque / per_raw)
            names.append(_label(name, owners.get(name), index, value.numel()))
    times, force, torque = result
    return Sensitivities(times=times, force=force, torque=torque, names=names,
                         force_jacobian=torch.stack(force_columns, dim=-1),
                         torque_jacobian=torch.stack(torque_columns, dim=-1))


def _value_per_raw(owner: BoundedParameter | None, dual_raw: Tensor) -> Tensor | float:
    """d value / d raw of a law parameter (1 for any other parameter)."""
    if owner is None:
        return 1.0
    _, slope = fwAD.unpack_dual(functional_call(owner, {"raw": dual_raw}, ()))
    return slope


def _label(name: str, owner: BoundedParameter | None, index: int, size: int) -> str:
    if owner is not None:
        return f"{owner.param_name} [{owner.unit}]"
    return name if size == 1 else f"{name}[{index}]"
