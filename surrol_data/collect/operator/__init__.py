"""The simulated human operator: a device driven by a model of human motor control (see :mod:`.operator`)."""

from surrol_data.collect.operator.operator import SimulatedOperator
from surrol_data.collect.operator.profiles import PROFILES, OperatorParams, operator_params

__all__ = ["PROFILES", "OperatorParams", "SimulatedOperator", "operator_params"]
