"""EMAC, Episodic Memory Actor-Critic (Kuznetsov & Filchenkov, IJCAI 2021), the thesis's Ch. 4 baseline."""

from sb3_gcrl.emac.emac import EMAC
from sb3_gcrl.emac.memory import EMACMemory, StateActionEmbedding
from sb3_gcrl.emac.policies import EMACPolicy, MultiInputEMACPolicy

__all__ = ["EMAC", "EMACMemory", "EMACPolicy", "MultiInputEMACPolicy", "StateActionEmbedding"]
