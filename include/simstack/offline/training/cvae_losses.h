#pragma once
/// @file cvae_losses.h
/// The training objective of the C-VAE and the FC baseline (paper section 3.1.3), plus the
/// terms not in the paper that the model config may weight in.

#include <torch/torch.h>

#include <vector>

#include "simstack/model/cvae.h"

namespace simstack {

/// Eq. 1: sum over voxels of |v - v_hat| / (|v| + eps), averaged over the batch.
torch::Tensor inverseTsdfWeightedLoss(const torch::Tensor& pred, const torch::Tensor& target,
                                      double eps);
/// Not in the paper: binary cross-entropy between sigmoid(-sharpness * pred) and the occupancy
/// target <= 0, summed over voxels and averaged over the batch (pred and target in units of tau).
torch::Tensor occupancyLoss(const torch::Tensor& pred, const torch::Tensor& target,
                            double sharpness);
/// Not in the paper: the Lovasz hinge of the occupancy logits -sharpness * pred against the
/// occupancy target <= 0 (a convex surrogate of 1 - IoU; equal to it when every hinge error is 0
/// or 1), averaged over the batch.
torch::Tensor iouLoss(const torch::Tensor& pred, const torch::Tensor& target, double sharpness);
/// Eq. 2: sum over voxels of the Euclidean norm of the vote error, averaged over the batch;
/// with `occupied_only`, only over voxels whose target vote is non-zero (inside an object);
/// with `weight` [B, 1, R, R, R], each voxel's norm weighted.
torch::Tensor voteLoss(const torch::Tensor& pred, const torch::Tensor& target,
                       bool occupied_only = false, const torch::Tensor& weight = {});
/// Maximum mean discrepancy between codes z [B, d] and prior samples [N, d] with the Gaussian
/// kernel exp(-|a - b|^2 / (w d)) averaged over the widths w (InfoVAE, Zhao et al. 2019, uses
/// w = 1), unbiased (zero in expectation when z follows the prior; may be slightly negative).
/// Both sets need at least two rows.
torch::Tensor mmdLoss(const torch::Tensor& z, const torch::Tensor& prior,
                      const std::vector<double>& widths = {1.0});

struct CvaeLosses {
  torch::Tensor total, tsdf, partial, votes, mmd, occupancy, iou;
};
/// The weighted sum of the paper's section 3.1.3 (MMD is 0 for the FC baseline), plus the
/// occupancy and IoU terms when their weights are not 0 (their values are reported either way).
/// With a learned prior the `mmd` slot holds KL(posterior || prior) (weight kl_weight, above its
/// free bits) instead. `vote_weight` [B, 1, R, R, R]: eq. 2's per-voxel weights (undefined: 1).
CvaeLosses computeLosses(const CvaeOutput& out, const torch::Tensor& partial,
                         const torch::Tensor& tsdf, const torch::Tensor& votes,
                         const CvaeConfig& config, const torch::Tensor& vote_weight = {});

}  // namespace simstack
