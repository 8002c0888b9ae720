"""The simulated human operator: a device driven by a model of human motor control (see :mod:`.operator`)."""

from surrol_data.collect.operator.operator import SimulatedOperator
from surrol_data.collect.operator.profiles import ALL_PROFILES, MATCHED_PROFILES, PROFILES, OperatorParams, operator_params

__all__ = ["ALL_PROFILES", "MATCHED_PROFILES", "PROFILES", "OperatorParams", "SimulatedOperator", "operator_params"]
