from sb3_gcrl.cec.cec import CEC
from sb3_gcrl.cec.policies import CECPolicy

__all__ = ["CEC", "CECPolicy"]
