"""Reinforcement learning on any system: a functional JAX environment, a Gymnasium adapter and reference scores.
See README.md in this folder. Importing this package registers the Gymnasium ids ``myriad/<Name>-v0`` (one per
shipped system, e.g. ``myriad/VanDerPol-v0``)."""

from .env import Env as Env
from .env import EnvOptions as EnvOptions
from .env import EnvState as EnvState
from .env import Episode as Episode
from .env import make_jax as make_jax
from .env import play as play
from .gym import MyriadEnv as MyriadEnv
from .gym import MyriadVectorEnv as MyriadVectorEnv
from .gym import env_id as env_id
from .gym import make as make
from .gym import register as register
from .gym import register_all as _register_all
from .optimum import CertificationError as CertificationError
from .reference import normalized_score as normalized_score
from .reference import reference_record as reference_record
from .reference import reference_scores as reference_scores

_register_all()

__all__ = [
    "Env", "EnvOptions", "EnvState", "Episode", "make_jax", "play",
    "MyriadEnv", "MyriadVectorEnv", "env_id", "make", "register",
    "CertificationError", "normalized_score", "reference_record", "reference_scores",
]
