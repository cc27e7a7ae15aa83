"""The DVC stages' scripts beyond ``python -m srmpc``: statistics, reports, figures, videos, the MLflow parent run.

Each module runs from the repository root as ``python -m pipelines.<module>`` (dvc.yaml, Makefile); what the
reports share (the table's methods, the paper's values, a method's row) is :mod:`pipelines.reporting`.
"""

import srmpc  # noqa: F401  (first: applies SRMPC_NUMERICS before any numeric library loads)
