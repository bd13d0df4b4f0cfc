"""The paper's training loss: BCE on U plus masked MSE on C, S, W and B.

    L = BCE(U, U_hat) + lambda_C MMSE(U, C, C_hat) + lambda_S MMSE(U, S, S_hat)
        + lambda_W MMSE(U, W, W_hat) + lambda_B MMSE(U, B, B_hat)
    MMSE(U, Y, Y_hat) = 1/N^2 sum_jk u_jk (y_jk - y_hat_jk)^2

The MMSE is weighted by the *ground-truth* U and divided by all N^2 pixels (not by the number of
grasp pixels), exactly as the paper's equation; it is averaged over the batch. Predictions outside
the ground-truth grasp zone therefore never change the C, S, W, B terms. ``U_hat`` is a logit
(see :mod:`planner.model`); the BCE is the mean over all pixels.

Outcome labels (:mod:`synth.data.outcomes`): the target carries a sixth channel, the BCE weight of
each pixel (tried centres high, untried low), and U is each tried centre's success value, so the
BCE is the weighted mean over all pixels and the MMSE terms are weighted by the success value.
The B term's weight follows the model's B encoding: ``lambda_b`` for cos(beta) (the paper's),
``lambda_beta`` for beta in 10 degree units (:mod:`planner.model`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LossWeights:
    lambda_b: float = 120.0  # balance MMSE weight [-]
    lambda_s: float = 30.0  # sin 2phi MMSE weight [-]
    lambda_c: float = 30.0  # cos 2phi MMSE weight [-]
    lambda_w: float = 60.0  # width MMSE weight [1/m^2]
    # BCE weight of positive U pixels [-]: 25, the shipped model's; 1 is the paper's plain BCE, which leaves U
    # flat on this data (docs/results/README.md, learning-curve-plain-bce: 17-25 % success against 67-79 %)
    u_pos_weight: float = 25.0
    # balance MMSE weight when B is beta in 10 deg units (planner.model "beta_10deg") [-]: with targets of order 1 the
    # term was 8.7 % of the validation loss of a short outcome-recipe run (docs/results/README.md, ranking-v3),
    # where lambda_b on cos(beta) (targets 0.98-1.0) left it ~1e-4 of the loss
    lambda_beta: float = 10.0

    def __post_init__(self) -> None:
        for k, v in vars(self).items():
            if not v >= 0:
                raise ValueError(f"loss weight {k} must be >= 0, got {v}")


def mmse(u, y, y_hat):
    """Masked MSE per the paper: mean over the batch of (1/N^2) sum u (y - y_hat)^2.

    ``u``, ``y``, ``y_hat``: (N, H, W) tensors."""
    return (u * (y - y_hat) ** 2).mean(dim=(-2, -1)).mean()


def grasp_loss(pred, target, weights: LossWeights = LossWeights(), b_encoding: str = "cos_beta"):
    """Total loss and its parts.

    ``pred``: (N, 5, H, W) model output (C, S, W, U-logit, B); ``target``: (N, 5, H, W) ground-truth
    maps (C, S, W, U in [0, 1], B in ``b_encoding``), or (N, 6, H, W) with the per-pixel BCE weight of
    U last (outcome labels). Returns ``(total, {"bce", "c", "s", "w", "b"})`` (parts as detached
    floats, unweighted)."""
    import torch.nn.functional as F

    if (pred.ndim != 4 or pred.shape[1] != 5 or target.ndim != 4 or target.shape[1] not in (5, 6)
            or pred.shape[0] != target.shape[0] or pred.shape[2:] != target.shape[2:]):
        raise ValueError(f"pred must be (N, 5, H, W) and target (N, 5 or 6, H, W) of the same N, H, W, got "
                         f"{tuple(pred.shape)} and {tuple(target.shape)}")
    pred = pred.float()
    target = target.float()
    u = target[:, 3]
    pos_weight = None
    if weights.u_pos_weight != 1.0:
        import torch

        pos_weight = torch.tensor(weights.u_pos_weight, device=pred.device)
    u_weight = target[:, 5] if target.shape[1] == 6 else None
    bce = F.binary_cross_entropy_with_logits(pred[:, 3], u, weight=u_weight, pos_weight=pos_weight)
    lc = mmse(u, target[:, 0], pred[:, 0])
    ls = mmse(u, target[:, 1], pred[:, 1])
    lw = mmse(u, target[:, 2], pred[:, 2])
    lb = mmse(u, target[:, 4], pred[:, 4])
    lambda_b = weights.lambda_beta if b_encoding == "beta_10deg" else weights.lambda_b
    total = bce + weights.lambda_c * lc + weights.lambda_s * ls + weights.lambda_w * lw + lambda_b * lb
    parts = {"bce": float(bce.detach()), "c": float(lc.detach()), "s": float(ls.detach()),
             "w": float(lw.detach()), "b": float(lb.detach())}
    return total, parts
