"""Studies from TOML config files (``jgi run``): see :mod:`jgi.experiment.study`.

* :mod:`~jgi.experiment.config` - reading and checking a config; the reduced (smoke) version
* :mod:`~jgi.experiment.plan` - the study's tasks, their seeds and result keys
* :mod:`~jgi.experiment.tasks` - running one task and writing its file atomically
* :mod:`~jgi.experiment.executors` - in this process, or on Dask (a LocalCluster or a scheduler)
* :mod:`~jgi.experiment.checkpoint` - one long render as seeded chunks (``jgi render --chunk-spp``)
* :mod:`~jgi.experiment.display` - progress of the study and of each task
* :mod:`~jgi.experiment.outputs` - plots, fitted slopes and error maps
"""

from .config import SMOKE_MAX, ConfigError, load_config, smoke, sweep_points
from .plan import plan, run_seed, study_scene
from .study import main_run, run

__all__ = ["ConfigError", "load_config", "smoke", "sweep_points", "SMOKE_MAX", "plan", "run_seed",
           "study_scene", "run", "main_run"]
