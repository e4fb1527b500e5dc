#pragma once
/// @file cvae_config.h
/// Plain configuration of the network (architecture and losses; the trainer's own settings are
/// in offline/training/train_config.h). No torch here: tools and the ROS layer read and
/// validate configs without the heavy headers.

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <string>
#include <vector>

namespace simstack {

/// Architecture and loss weights (paper section 3.1 and Appendix C). Stored inside every model
/// file, so that a file rebuilds its own network.
struct CvaeConfig {
  /// "cvae" (the paper's model); "fc": the C-VAE without its code, decoding the conditioning
  /// encoder's maps at every scale (our ablation: it isolates what the code adds); "fc_plain":
  /// the FC baseline as the paper's section 4.1 and Appendix C draw it, an encoder whose
  /// deepest features alone are decoded by two task branches (no encoder maps at finer scales).
  std::string architecture = "cvae";
  int resolution = 32;          ///< R; the paper's 64 is a configuration
  double extent_m = 0.64;       ///< side of the scene grid
  double truncation_vox = 3.0;  ///< tau in voxels; the network sees tsdf / tau
  int base_channels = 8;        ///< width of the first stage; doubles per stage
  int max_channels = 64;        ///< cap of the deepest widths (they hold most parameters)
  int latent_size = 96;         ///< VAE latent z
  int condition_size = 96;      ///< bottleneck of the conditioning autoencoder
  int hidden_size = 128;        ///< width of the hidden linear layer on either side
  /// Normalisation in every convolution block: "batch" (the paper's BatchNorm) or "group"
  /// (GroupNorm, 4 channels per group). In training mode BatchNorm makes each sample's code
  /// depend on the rest of its batch, which the MMD estimate assumes it does not (README).
  std::string norm = "batch";
  // Loss weights of L = alpha L_tsdf + beta L_ptsdf + gamma L_votes + delta MMD
  // (+ occupancy_weight L_occ, below).
  double alpha = 1.0;
  double beta = 1.0;
  double gamma = 1.0;
  double delta = 1e5;
  /// Prior draws per step in the MMD estimate (the batch's codes are the other set). The
  /// models up to models/simstack_r32.pt drew as many as the batch (8) and kept the diagonal:
  /// for a batch that follows the prior that estimate is 0.21 +- 0.010 (latent 96); unbiased
  /// with 256 draws it is 0 +- 0.0056, the rest of the noise being the batch's own 8 codes.
  int mmd_prior_samples = 256;
  /// Widths of the MMD's Gaussian kernels in units of the latent size: the kernel is the mean
  /// over widths w of exp(-|a - b|^2 / (w * latent_size)). With the single width 1 (InfoVAE's
  /// choice), codes pinned near the prior's centre mixed with wide noise (what our encoders
  /// learned) score an MMD of 0.005, a shift of the prior by 0.3 scores 0.025; with widths
  /// 0.2, 1 and 5 the mixture scores 0.036 (512 codes, latent 96).
  std::vector<double> mmd_kernel_widths = {1.0};
  /// epsilon of eq. 1 in units of tau. The paper's 1e-9 gives voxels that happen to lie on the
  /// surface weights up to 1e9; 0.01 caps them at 100x.
  double tsdf_epsilon = 0.01;
  /// Weight of an occupancy term that is not in the paper: the binary cross-entropy between
  /// sigmoid(-occupancy_sharpness * tsdf / tau) and the ground-truth occupancy (tsdf <= 0, eq. 8's
  /// definition), summed over voxels like eq. 1. Eq. 1 weights a voxel by its distance to the
  /// surface, not by which side of it the prediction lies, and the evaluation's IoU and BCE
  /// score only the side. 0 (the default) is the paper's loss.
  double occupancy_weight = 0.0;
  /// Slope of that sigmoid: a prediction of +-1/occupancy_sharpness tau is 73 % sure.
  double occupancy_sharpness = 10.0;
  /// Weight of the Lovasz hinge (Berman et al. 2018), a convex surrogate of 1 - IoU per sample,
  /// on the logits -occupancy_sharpness * tsdf / tau: the evaluation's IoU as a loss. 0 = off.
  double iou_weight = 0.0;
  /// Voxels where eq. 2 is summed: "occupied" (ground-truth occupied voxels, whose votes the
  /// Hough step reads) or "all" (the paper: every voxel, target zero outside objects). With
  /// "all" the ~30,000 free voxels pull every vote to zero with unit-size gradients, and our
  /// models learned zero votes everywhere (loss = number of occupied voxels).
  std::string vote_loss = "occupied";
  /// Eq. 2's weight in occupied voxels within 2 voxels (26-neighbourhood twice) of another
  /// object's voxel is 1 + this: the votes there are what tells touching objects apart, and
  /// they are a small share of the sum. 0 (the default) weighs every voxel alike.
  double vote_boundary_weight = 0.0;
  /// Training only: the probability that a sample's decoder loses the condition's two finest
  /// feature maps (32^3 and 16^3 at R = 32) for that step, so that it must take the shape from
  /// coarser features and the latent code. 0 (the default) never drops them; inference never
  /// does.
  double condition_dropout = 0.0;
  /// Where the C-VAE's decoder reads the latent code: "bottleneck" (the paper: z becomes the
  /// deepest feature map, and the condition's maps join at every scale) or "every_scale" (z is
  /// also projected to a per-channel offset added before each of the decoder's joint blocks,
  /// down to the finest grid, as the probabilistic U-Net feeds its code to the last layers)
  /// or "condition" (the deepest map is the condition's own, as in `fc`, plus a projection of z
  /// whose last layer starts at zero: a C-VAE warm-started from an `fc` model begins as that
  /// model for every code, and training teaches the code what the condition leaves open).
  /// A network setting, stored with the model; the FC baseline has no code and ignores it.
  std::string latent_injection = "bottleneck";
  /// What the condition tells the network about voxels the view did not observe: "full" (the
  /// paper: all its feature maps everywhere) or "coarse" (its two finest maps, 32^3 and 16^3
  /// at R = 32, are zero in unobserved voxels and in 16^3 cells with no observed voxel, for the
  /// decoder and the posterior encoder, so the hidden part's shape must come from the coarser
  /// maps and the latent code; `fc_plain` reads neither map). A network setting, stored with
  /// the model; inference masks the same way.
  std::string hidden_condition = "full";
  /// How a training step draws the code from the encoder: "gaussian" (z = mu + sigma * noise,
  /// the reparameterised sample) or "deterministic" (z = mu, the MMD autoencoder of InfoVAE's
  /// tutorial and of WAE-MMD: the MMD alone makes the codes look like the prior, and the
  /// decoder sees the code without noise). Our Gaussian encoders settled at sigma 2 with mu of
  /// RMS 0.1-0.7: such a z is mostly noise, the decoder learned to ignore it, and then nothing
  /// made sigma shrink (README). Inference draws codes from the prior either way.
  std::string posterior = "gaussian";
  /// The distribution codes are drawn from: "standard" (N(0, I), the paper; the MMD term pulls
  /// the encoder's codes towards it) or "learned" (the standard C-VAE's conditional prior
  /// p(z | view) = N(mu(c), sigma(c)^2) from the condition's deepest map, trained by
  /// KL(posterior || prior) weighted by `kl_weight` in place of the MMD). A network setting.
  /// Inference still draws standard normal e; a learned prior decodes mu(c) + sigma(c) e, so
  /// the zero code is the prior's mean for this view.
  std::string prior = "standard";
  double kl_weight = 1.0;
  /// Free bits: the KL term counts each code dimension's batch-mean KL only above
  /// kl_free_nats / latent_size, so that the code may carry that many nats at no cost (a KL
  /// that is cheap to squeeze out of the code otherwise leaves it empty). 0 = off.
  double kl_free_nats = 0.0;
  /// Training only: each scene decodes this many codes drawn from its posterior, and the
  /// reconstruction terms (eq. 1, eq. 2, occupancy, IoU) are those of the code that scores best
  /// ("best of many samples", Bhattacharyya et al., CVPR 2018; the minimum over samples of
  /// implicit maximum likelihood estimation). One completion must fit the truth, the others
  /// may differ where the view does not decide; 1 (the default) is the paper's single code.
  int best_of = 1;

  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
  std::string toYaml() const;
  /// Only the C-VAE has a latent code; the FC networks give one deterministic prediction.
  bool hasLatentCode() const { return architecture == "cvae"; }
  /// Whether the decoder reads the condition's map at every scale (all but the plain FC).
  bool decoderReadsEveryConditionMap() const { return architecture != "fc_plain"; }
  /// Parses YAML text (fields absent keep their defaults); throws std::invalid_argument.
  static CvaeConfig fromYaml(const std::string& text);
  /// Takes the loss weights and settings (not the network) of `other`.
  void copyLossSettings(const CvaeConfig& other);
  double voxelSize() const { return extent_m / resolution; }
  double truncation_m() const { return truncation_vox * voxelSize(); }
};

/// The `model:` section of a training file (simstack_train --config), its dropped variants
/// under `experimental:`: fields it does not know are refused; std::invalid_argument naming
/// the field ("model.latent_size").
CvaeConfig cvaeConfigFromSection(const YAML::Node& section);

/// The card of a model file: the same path with the extension .yaml.
std::string modelCardPath(const std::string& model_path);

/// The model card at `card_path`, read: a map whose sections are those a card holds (model,
/// training, provenance, perception, evaluation, integrity). A misspelt section would leave
/// the card's Hough setting or checksum unread: std::runtime_error naming the file and key.
YAML::Node loadModelCard(const std::string& card_path);

}  // namespace simstack
