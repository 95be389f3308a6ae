"""lcGAN: the data-driven lane-change prior P_lcGAN (paper §III.C.1, Eq. 16-19).

A conditional GAN whose generator ``G(Z, C)`` (Eq. 16) outputs a probability vector over the lane-change
actions (left, keep, right) and whose discriminator ``D(P, C)`` (Eq. 17) scores whether a probability
vector is a real human action (one-hot) or a generated one, both conditioned on ``C = {S_AV, S_SV, y_pre}``.

Condition C: its fields are built by :func:`kddrl_trl.generative.gan_inputs.lane_change_condition`, from the tracks for
the ``lane_changes`` samples of :mod:`kddrl_trl.data.extract` and from the raw observation at RL time
(:class:`LCGANPredictor`); :meth:`LCGenerator.condition` assembles and normalises them:

=================  ====  =====================================================================
part               size  content
=================  ====  =====================================================================
S_AV               4     ego speed v, lateral speed (+ = left), lane index as float, lateral offset
                         from its lane's centre (m, + = left); normalised
lane availability  2     1.0 where a left (lane < num_lanes - 1) / right (lane > 0) lane exists
S_SV               24+6  ``rel`` of slots a..f (dx, dy, dvx, dvy), normalised per slot and feature
                   +6    over *present* slots, 0 where absent; the 6 presence flags; each neighbour's
                         offset from its own lane's centre (``lane_offset``), normalised per slot
y_pre              6+3   key gaps of leaders a, b, c at steps 10 and 20 (m), normalised per slot and
                         step over present leaders, 0 where absent; plus the 3 presence flags
=================  ====  =====================================================================

``y_pre`` is the *true* future of the leaders during pretraining (teacher forcing, as the extractor saves
it); at RL time it is the trajGAN prediction ``keys.PRED_KEY_GAPS``. The normalisation statistics are
computed once from the train split and kept as buffers of :class:`LCGenerator`, so every checkpoint (and
the predictor built from one) carries them. Standard deviations are floored at 0.1 (m or m/s) so that
near-constant features (lateral relative speeds) cannot blow up.

Impossible directions (left from the leftmost lane, right from lane 0) get probability exactly 0: their
logits are masked before the softmax, during training and inference alike.

Losses (:meth:`LCGANTask.train_batch`):

* D, Eq. 18: binary cross-entropy of D on real one-hot actions (target 1) and on generated probability
  vectors (target 0), computed with ``BCEWithLogitsLoss`` on D's logit (numerically safe form of the
  ``log D`` / ``log(1 - D)`` terms).
* G, Eq. 19: the non-saturating adversarial term ``-log D(G(Z, C), C)`` (again ``BCEWithLogitsLoss``) plus
  ``ω`` times the focal loss ``-α_k (1 - p_k)^γ log p_k`` of the true class k (:func:`focal_loss`), γ = 2.

Class imbalance (≈0.3 % left, ≈0.4 % right) is handled by two knobs: the class weights ``α`` and
class-balanced mini-batches (``balanced_fraction``: that share of every mini-batch is drawn, with
replacement and half per class, from the train split's left and right samples). ``α`` is computed from the
class frequencies of the mini-batch stream the model actually sees (train frequencies mixed with the
balanced share), so the two knobs never double count: ``"inv_sqrt"`` (default) = ``1 / sqrt(freq)``
normalised to mean 1, ``"inv"`` = ``1 / freq`` normalised to mean 1, ``"none"`` = 1, or 3 explicit numbers.
Default: a 25 % balanced share plus ``"inv_sqrt"``. On the SUMO baseline dataset, α alone (no balanced
share, even with ``"inv"``) reached a validation balanced accuracy of 0.68 against 0.79 with the share: with
~3 lane changes per mini-batch of 512 the rare-class gradient is too noisy, whatever its weight.

With ``adversarial=False`` the same generator network is trained as a plain classifier with the focal loss
only (the baseline ``benchmarks/lcgan_ablation.py`` compares the GAN with); the checkpoint then holds no
discriminator.

Model selection: :meth:`LCGANTask.validation_loss` is ``1 - balanced accuracy`` (mean per-class recall of
``argmax P``), so early stopping looks at the rare classes, not at the 99 % of lane keeping. Epochs are
40k-sample subsets (``conf/gan/lcgan.yaml``): with the balanced share a full epoch repeats each train lane change
~12 times and overfits the rare classes within one epoch. Measured (``benchmarks/lcgan_ablation.py``, 3 seeds):
the adversarial term does not improve on the plain classifier (balanced accuracy 81.3 vs 81.5 %); the
argmax of the balanced-trained P over-predicts lane changes (precision ~17 %), so P is not calibrated to the
natural class frequencies.
=================  ===========================================================================
file               content
=================  ===========================================================================
``model.py``       condition normalisation, generator and discriminator networks (Eq. 16-17)
``losses.py``      focal loss and class weights (Eq. 19)
``task.py``        :class:`LCGANTask` for :func:`~kddrl_trl.generative.pretraining.run_pretraining`
``metrics.py``     classification metrics and the MOBIL baseline
``figures.py``     figures of the test evaluation
``predictor.py``   :class:`LCGANPredictor`, the batched, gradient-free inference module of the environment
=================  ===========================================================================
"""

from .losses import class_weights, focal_loss
from .metrics import classification_metrics, mobil_probabilities
from .model import KIND, LCDiscriminator, LCGenerator, condition_size, lane_availability
from .predictor import LCGANPredictor
from .task import LCGANConfig, LCGANTask

__all__ = [
    "KIND",
    "LCDiscriminator",
    "LCGANConfig",
    "LCGANPredictor",
    "LCGANTask",
    "LCGenerator",
    "class_weights",
    "classification_metrics",
    "condition_size",
    "focal_loss",
    "lane_availability",
    "mobil_probabilities",
]
