from sb3_gcrl.mfec.mfec import MFEC
from sb3_gcrl.mfec.policies import MFECPolicy

__all__ = ["MFEC", "MFECPolicy"]
