"""What a run shows goes through Python's logging, under the ``sfmnet`` logger.

Under the command line, Hydra's job logging (``hydra.job_logging`` in ``conf/train.yaml``) puts
each line on the console, bare, and in the run's ``train.log`` with its time. The Python API has
no Hydra to configure logging: :func:`lines_to_stdout` shows the lines for its ``verbose``.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator

LOGGER = "sfmnet"


@contextlib.contextmanager
def lines_to_stdout() -> Iterator[None]:
    """While inside, the ``sfmnet`` logger's lines (INFO and up) on stdout, bare, and not passed on to the root logger."""
    logger = logging.getLogger(LOGGER)
    handler = logging.StreamHandler(sys.stdout)
    handler.setFormatter(logging.Formatter("%(message)s"))
    level, propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate
