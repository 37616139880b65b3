"""The robot's side: an explorer that runs on measured data alone (never imports the simulator).

>>> from superex_deploy.onboard import Explorer, ExplorerConfig
"""

from superex_deploy.onboard.explorer import STAGES, Explorer, ExplorerConfig, PredictionSchedule
from superex_deploy.onboard.prediction.reuse import PredictionReuse
from superex_deploy.onboard.nlos.processing import SpadProcessing, scan_from_frame
from superex_deploy.onboard.planning.bounds import ExplorationBounds
from superex_deploy.onboard.planning.goal_policy import GoalPolicy

__all__ = ["STAGES", "Explorer", "ExplorerConfig", "PredictionSchedule", "PredictionReuse", "SpadProcessing",
           "scan_from_frame", "ExplorationBounds", "GoalPolicy"]
