#include "simstack/offline/training/cvae_losses.h"

#include <stdexcept>
#include <string>
#include <tuple>

namespace simstack {
namespace {

namespace F = torch::nn::functional;

/// The loss terms per sample [B], before the batch mean.
torch::Tensor tsdfTermPerSample(const torch::Tensor& pred, const torch::Tensor& target,
                                double eps) {
  return ((pred - target).abs() / (target.abs() + eps)).flatten(1).sum(1);
}

torch::Tensor occupancyTermPerSample(const torch::Tensor& pred, const torch::Tensor& target,
                                     double sharpness) {
  const torch::Tensor occupied = (target <= 0).to(pred.dtype());
  return F::binary_cross_entropy_with_logits(
             -sharpness * pred, occupied,
             F::BinaryCrossEntropyWithLogitsFuncOptions().reduction(torch::kNone))
      .flatten(1)
      .sum(1);
}

/// Lovasz hinge per sample: the Lovasz extension of the Jaccard loss evaluated on the hinge
/// errors of the occupancy logits, sorted from the worst.
torch::Tensor iouTermPerSample(const torch::Tensor& pred, const torch::Tensor& target,
                               double sharpness) {
  const torch::Tensor logits = (-sharpness * pred).flatten(1);
  const torch::Tensor occupied = (target <= 0).to(pred.dtype()).flatten(1);
  const torch::Tensor errors = 1.0 - logits * (2.0 * occupied - 1.0);
  const auto [sorted, order] = errors.sort(1, /*descending=*/true);
  torch::Tensor jaccard_step;
  {
    torch::NoGradGuard no_grad;
    const torch::Tensor gt = occupied.gather(1, order);
    const torch::Tensor total = gt.sum(1, true);
    const torch::Tensor jaccard = 1.0 - (total - gt.cumsum(1)) / (total + (1.0 - gt).cumsum(1));
    const int64_t n = jaccard.size(1);
    jaccard_step = torch::cat(
        {jaccard.narrow(1, 0, 1), jaccard.narrow(1, 1, n - 1) - jaccard.narrow(1, 0, n - 1)}, 1);
  }
  return (F::relu(sorted) * jaccard_step).sum(1);
}

torch::Tensor voteTermPerSample(const torch::Tensor& pred, const torch::Tensor& target,
                                bool occupied_only, const torch::Tensor& weight) {
  // sqrt(. + 1e-12): the norm's gradient is undefined where prediction and target agree.
  torch::Tensor per_voxel = ((pred - target).pow(2).sum(1) + 1e-12).sqrt();
  if (occupied_only) per_voxel = per_voxel * (target.pow(2).sum(1) > 0.25).to(per_voxel.dtype());
  if (weight.defined()) per_voxel = per_voxel * weight.squeeze(1);
  return per_voxel.flatten(1).sum(1);
}

}  // namespace

torch::Tensor inverseTsdfWeightedLoss(const torch::Tensor& pred, const torch::Tensor& target,
                                      double eps) {
  return tsdfTermPerSample(pred, target, eps).mean();
}

torch::Tensor occupancyLoss(const torch::Tensor& pred, const torch::Tensor& target,
                            double sharpness) {
  return occupancyTermPerSample(pred, target, sharpness).mean();
}

torch::Tensor iouLoss(const torch::Tensor& pred, const torch::Tensor& target, double sharpness) {
  return iouTermPerSample(pred, target, sharpness).mean();
}

torch::Tensor voteLoss(const torch::Tensor& pred, const torch::Tensor& target, bool occupied_only,
                       const torch::Tensor& weight) {
  return voteTermPerSample(pred, target, occupied_only, weight).mean();
}

torch::Tensor mmdLoss(const torch::Tensor& z, const torch::Tensor& prior,
                      const std::vector<double>& widths) {
  if (z.size(0) < 2 || prior.size(0) < 2)
    throw std::invalid_argument("MMD needs at least two codes and two prior samples");
  if (widths.empty()) throw std::invalid_argument("MMD needs at least one kernel width");
  const double d = static_cast<double>(z.size(1));
  auto kernel = [&](const torch::Tensor& a, const torch::Tensor& b) {
    // |a|^2 + |b|^2 - 2 a.b: N x M, never the N x M x d differences (4096 prior draws of 256
    // dimensions would take 17 GB); rounding below 0 is clamped (a code's distance to itself).
    const torch::Tensor sq =
        (a.pow(2).sum(1, true) + b.pow(2).sum(1).unsqueeze(0) - 2.0 * a.matmul(b.t())).clamp_min(0);
    torch::Tensor k = torch::zeros_like(sq);
    for (double w : widths) k = k + torch::exp(-sq / (w * d));
    return k / static_cast<double>(widths.size());
  };
  // Unbiased: a set's kernel with itself leaves out the diagonal (each k(x, x) = 1).
  auto within = [&](const torch::Tensor& a) {
    const double n = static_cast<double>(a.size(0));
    return (kernel(a, a).sum() - n) / (n * (n - 1.0));
  };
  return within(z) + within(prior) - 2.0 * kernel(z, prior).mean();
}

CvaeLosses computeLosses(const CvaeOutput& out, const torch::Tensor& partial,
                         const torch::Tensor& tsdf, const torch::Tensor& votes, const CvaeConfig& c,
                         const torch::Tensor& vote_weight) {
  CvaeLosses l;
  // k codes per scene (best_of), scene-major: the targets repeat to match.
  const int64_t scenes = tsdf.size(0), k = out.tsdf.size(0) / scenes;
  if (k * scenes != out.tsdf.size(0))
    throw std::invalid_argument("computeLosses: " + std::to_string(out.tsdf.size(0)) +
                                " predictions for " + std::to_string(scenes) + " scenes");
  auto repeat = [k](const torch::Tensor& t) {
    return k > 1 && t.defined() ? t.repeat_interleave(k, 0) : t;
  };
  torch::Tensor tsdf_term = tsdfTermPerSample(out.tsdf, repeat(tsdf), c.tsdf_epsilon);
  torch::Tensor vote_term =
      voteTermPerSample(out.votes, repeat(votes), c.vote_loss == "occupied", repeat(vote_weight));
  torch::Tensor occupancy_term;
  {
    // Reported also at weight 0, then without a graph: it is not trained.
    torch::AutoGradMode grad(torch::GradMode::is_enabled() && c.occupancy_weight > 0.0);
    occupancy_term = occupancyTermPerSample(out.tsdf, repeat(tsdf), c.occupancy_sharpness);
  }
  torch::Tensor iou_term;
  {
    torch::AutoGradMode grad(torch::GradMode::is_enabled() && c.iou_weight > 0.0);
    iou_term = iouTermPerSample(out.tsdf, repeat(tsdf), c.occupancy_sharpness);
  }
  if (k > 1) {
    // Each scene keeps the code whose reconstruction scores best; only it is trained.
    const torch::Tensor score = (c.alpha * tsdf_term + c.gamma * vote_term +
                                 c.occupancy_weight * occupancy_term + c.iou_weight * iou_term)
                                    .detach()
                                    .view({scenes, k});
    const torch::Tensor best =
        score.argmin(1) + torch::arange(scenes, score.options().dtype(torch::kLong)) * k;
    tsdf_term = tsdf_term.index_select(0, best);
    vote_term = vote_term.index_select(0, best);
    occupancy_term = occupancy_term.index_select(0, best);
    iou_term = iou_term.index_select(0, best);
  }
  l.tsdf = tsdf_term.mean();
  l.partial = inverseTsdfWeightedLoss(out.partial_recon, partial.narrow(1, 0, 1), c.tsdf_epsilon);
  l.votes = vote_term.mean();
  torch::Tensor latent;  // the weighted latent term of the total
  if (out.prior_mu.defined()) {
    // KL(N(mu, e^logvar) || N(prior_mu, e^prior_logvar)) per code dimension, batch mean;
    // with free bits each dimension counts only above its share of kl_free_nats.
    const torch::Tensor d = out.mu - out.prior_mu;
    const torch::Tensor per_dim =
        (0.5 * (out.prior_logvar - out.logvar +
                (torch::exp(out.logvar) + d * d) * torch::exp(-out.prior_logvar) - 1.0))
            .mean(0);
    l.mmd = per_dim.sum();  // reported as it is
    latent =
        c.kl_weight *
        (c.kl_free_nats > 0.0 ? per_dim.clamp_min(c.kl_free_nats / per_dim.size(0)).sum() : l.mmd);
  } else {
    // One code per scene: a scene's best_of codes share its posterior, and the estimator's
    // pairs within the codes must be independent draws (with all k of them, codes that follow
    // the prior still score far above zero, and the term pulls every posterior to N(0, I)).
    const torch::Tensor z =
        out.z.defined() && k > 1 ? out.z.view({scenes, k, -1}).select(1, 0) : out.z;
    l.mmd = z.defined() ? mmdLoss(z, torch::randn({c.mmd_prior_samples, z.size(1)}, z.options()),
                                  c.mmd_kernel_widths)
                        : torch::zeros({}, tsdf.options());
    latent = c.delta * l.mmd;
  }
  l.occupancy = occupancy_term.mean();
  l.iou = iou_term.mean();
  l.total = c.alpha * l.tsdf + c.beta * l.partial + c.gamma * l.votes + latent +
            c.occupancy_weight * l.occupancy + c.iou_weight * l.iou;
  return l;
}

}  // namespace simstack
