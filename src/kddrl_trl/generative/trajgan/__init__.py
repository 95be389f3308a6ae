"""trajGAN: intention-aware trajectories of the leading vehicles (paper §III.B, Eq. 13-15).

The IDM prior ``TC`` (Eq. 11-12, ``prior`` of the ``leaders`` samples, ``keys.PRED_PRIOR_TRAJ`` in the
environment) is refined by a conditional GAN: the generator ``G(Z, TC)`` (Eq. 13) outputs the 20 future
positions as a *residual on the prior*, ``TG = TC + G``, and the discriminator ``D(trajectory, TC)`` tells
real futures ``TR`` from generated ones.

=================  ===========================================================================
file               content
=================  ===========================================================================
``model.py``       condition features, generator and discriminator networks, ``TG = TC + G``
``task.py``        :class:`TrajGANTask` (Eq. 14-15) for :func:`~kddrl_trl.generative.pretraining.run_pretraining`
``figures.py``     figures of the test evaluation
``predictor.py``   :class:`TrajGANPredictor`, the batched, gradient-free inference module of the environment
=================  ===========================================================================
"""

from .model import FEATURES_VERSION, KIND, TrajDiscriminator, TrajGenerator, condition_features
from .predictor import TrajGANPredictor
from .task import RECOMMENDED_PRETRAIN, TrajGANConfig, TrajGANTask

__all__ = [
    "FEATURES_VERSION",
    "KIND",
    "RECOMMENDED_PRETRAIN",
    "TrajDiscriminator",
    "TrajGANConfig",
    "TrajGANPredictor",
    "TrajGANTask",
    "TrajGenerator",
    "condition_features",
]
