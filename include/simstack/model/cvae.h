#pragma once
/// @file cvae.h
/// The depth-conditioned VAE of the paper (section 3.1.1, Appendix C) and its FC ablation, in
/// libtorch. One definition serves training and inference. Heavy header: include it only in
/// the model's own translation units (inference users take cvae_inference.h).
///
/// Tensors are [B, C, D, H, W] = [B, C, z, y, x] on the scene grid; TSDFs are divided by tau.
///   partial  [B, 2, R, R, R]  channel 0: partial TSDF / tau, channel 1: observed (0/1)
///   tsdf     [B, 1, R, R, R]  full TSDF / tau in [-1, 1]
///   votes    [B, 3, R, R, R]  unit vectors to object centroids, 0 outside objects

#include <torch/torch.h>

#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "simstack/model/cvae_config.h"

namespace simstack {

/// Tensors computed from parameters for inference (BatchNorm folded into the convolution
/// before it, weights split by input channels), kept until a parameter they came from changes:
/// an in-place update bumps its version counter, a replacement changes its storage.
class DerivedWeights {
 public:
  /// The cached tensors if `sources` are unchanged since they were made, else compute().
  /// `variant` tells apart derivations of the same sources. Thread-safe.
  std::vector<torch::Tensor> get(const std::vector<torch::Tensor>& sources, int variant,
                                 const std::function<std::vector<torch::Tensor>()>& compute);

 private:
  std::vector<std::pair<const void*, int64_t>> keys_;
  std::vector<torch::Tensor> values_;
  std::shared_ptr<std::mutex> mutex_ = std::make_shared<std::mutex>();
};

/// Conv3d(3x3x3) + BatchNorm (or GroupNorm) + PReLU. At inference (no grad) the convolution
/// calls oneDNN directly: libtorch 1.13's CPU build skips it for 3D convolutions otherwise
/// (docs/experiments.md, "Runtime"); with BatchNorm in eval mode, the normalisation is folded into
/// it.
class ConvBlockImpl : public torch::nn::Module {
 public:
  ConvBlockImpl(int in, int out, int stride, bool group_norm = false);
  torch::Tensor forward(const torch::Tensor& x);
  /// The inference fast path applies: eval mode, no gradients, BatchNorm.
  bool folds() const;
  /// The convolution's weight and bias with the eval-mode BatchNorm after it folded in:
  /// conv(x, W) * s + t = conv(x, W * s) + t, s = gamma / sqrt(var + eps), t = beta - mean * s.
  /// `split` > 0 also gives the folded weight's input channels [0, split) and [split, in) as
  /// contiguous tensors (elements 2 and 3).
  std::vector<torch::Tensor> folded(int split = 0);
  /// The PReLU's slope (one for all channels).
  const torch::Tensor& activationWeight() const { return act->weight; }
  int stride() const { return stride_; }

 private:
  torch::nn::Conv3d conv{nullptr};
  torch::nn::BatchNorm3d bn{nullptr};
  torch::nn::GroupNorm gn{nullptr};
  torch::nn::PReLU act{nullptr};
  int stride_;
  DerivedWeights folded_;
};
TORCH_MODULE(ConvBlock);

/// Residual block with squeeze-and-excitation (He et al. 2016; Hu et al. 2018).
class ResSEBlockImpl : public torch::nn::Module {
 public:
  ResSEBlockImpl(int in, int out, int stride, bool group_norm = false);
  torch::Tensor forward(const torch::Tensor& x);
  /// The block applied to cat(x, c) along channels. `c` may have batch 1 against x's B (one
  /// condition shared by B codes): at inference the convolutions that read the input then run
  /// on x and on the single c apart and add (conv(cat(x, c), W) = conv(x, W_x) + conv(c, W_c)),
  /// so the condition's half of the work is done once instead of B times.
  torch::Tensor forwardWithCondition(const torch::Tensor& x, const torch::Tensor& c);

 private:
  torch::Tensor finish(const torch::Tensor& a_out, const torch::Tensor& shortcut);

  ConvBlock a{nullptr};
  torch::nn::Conv3d b{nullptr};
  torch::nn::BatchNorm3d bn{nullptr};
  torch::nn::GroupNorm gn{nullptr};
  torch::nn::Linear se1{nullptr}, se2{nullptr};
  torch::nn::Conv3d skip{nullptr};
  torch::nn::PReLU act{nullptr};
  DerivedWeights folded_b_, split_skip_;
};
TORCH_MODULE(ResSEBlock);

/// 2x upsampling by "voxel shuffle": a 1x1x1 convolution to 8x the channels rearranged into
/// the doubled grid, exactly a ConvTranspose3d(kernel 2, stride 2) but on oneDNN's fast path.
class UpsampleImpl : public torch::nn::Module {
 public:
  UpsampleImpl(int in, int out);
  torch::Tensor forward(const torch::Tensor& x);

 private:
  torch::nn::Conv3d conv{nullptr};
  int out_;
};
TORCH_MODULE(Upsample);

/// What one forward pass gives.
struct CvaeOutput {
  torch::Tensor tsdf;           ///< [B, 1, R, R, R], tanh
  torch::Tensor votes;          ///< [B, 3, R, R, R]
  torch::Tensor partial_recon;  ///< [B, 1, R, R, R], the conditioning autoencoder's output
  torch::Tensor mu, logvar, z;  ///< [B, latent] (undefined for the FC baseline)
  /// The conditional prior's N(prior_mu, exp(prior_logvar)) (training pass, learned prior only).
  torch::Tensor prior_mu, prior_logvar;
};

class CvaeImpl : public torch::nn::Module {
 public:
  explicit CvaeImpl(const CvaeConfig& config);
  /// Training pass: encodes (tsdf, votes) with the condition, samples z by reparametrisation.
  CvaeOutput forward(const torch::Tensor& partial, const torch::Tensor& tsdf,
                     const torch::Tensor& votes);
  /// Generation: decodes codes z [B, latent] conditioned on `partial` [B or 1, 2, R, R, R]; a
  /// single condition is encoded once and shared by all codes. The FC baseline ignores z.
  /// With a learned prior the rows of z are standard normal draws e, decoded as the codes
  /// mu(c) + sigma(c) e of the view's prior.
  CvaeOutput generate(const torch::Tensor& partial, const torch::Tensor& z);
  /// Decodes exactly the codes z (no prior applied): a posterior code, or an optimised one.
  CvaeOutput decodeCodes(const torch::Tensor& partial, const torch::Tensor& z);
  /// The posterior's mean code [B, latent] for the truth (tsdf, votes) seen as `partial`; draws
  /// nothing. A model with a code only.
  torch::Tensor posteriorMean(const torch::Tensor& partial, const torch::Tensor& tsdf,
                              const torch::Tensor& votes);
  /// The condition's feature maps, finest first: encode once, then generateFrom() any codes.
  std::vector<torch::Tensor> encodeCondition(const torch::Tensor& partial);
  /// generate() with the condition already encoded.
  CvaeOutput generateFrom(const std::vector<torch::Tensor>& cond, const torch::Tensor& z);
  const CvaeConfig& config() const { return config_; }
  /// Replaces the stored config by one that describes the same network (only the loss
  /// settings may differ); throws std::invalid_argument otherwise.
  void setConfig(const CvaeConfig& config);

 private:
  torch::Tensor decodeCondition(const torch::Tensor& features);
  /// The posterior N(mu, exp(logvar)) of (tsdf, votes) given the condition's maps.
  std::pair<torch::Tensor, torch::Tensor> encodePosterior(const std::vector<torch::Tensor>& cond,
                                                          const torch::Tensor& tsdf,
                                                          const torch::Tensor& votes);
  /// `z` is undefined for the FC baseline; with latent_injection "every_scale" it is added, as
  /// projected per-channel offsets, before each joint block.
  CvaeOutput decode(const torch::Tensor& bottleneck, const std::vector<torch::Tensor>& cond,
                    const torch::Tensor& z = {});
  /// The codes z [B, latent] decoded with the encoded condition `cond` (one or B conditions).
  CvaeOutput decodeWith(const std::vector<torch::Tensor>& cond, const torch::Tensor& z);
  /// The learned prior's mean and log-variance for the encoded condition.
  std::pair<torch::Tensor, torch::Tensor> priorOf(const std::vector<torch::Tensor>& cond);

  CvaeConfig config_;
  std::vector<int> widths_;  // per stage: R, R/2, R/4, R/8, R/16
  int bottom_ = 2;           // side of the deepest grid
  // Conditioning autoencoder.
  std::vector<ConvBlock> cond_enc_;
  torch::nn::Linear cond_fc1{nullptr}, cond_fc2{nullptr}, cond_dfc1{nullptr}, cond_dfc2{nullptr};
  std::vector<Upsample> cond_up_;
  std::vector<ConvBlock> cond_dec_;
  torch::nn::Conv3d cond_head{nullptr};
  // VAE encoder (training only).
  ConvBlock enc_tsdf1{nullptr}, enc_tsdf2{nullptr}, enc_votes1{nullptr}, enc_votes2{nullptr};
  std::vector<ResSEBlock> enc_joint_;
  torch::nn::Linear enc_mu{nullptr}, enc_logvar{nullptr};
  torch::nn::Linear prior_mu{nullptr}, prior_logvar{nullptr};  // prior "learned"
  // Decoder.
  torch::nn::Linear dec_fc1{nullptr}, dec_fc2{nullptr};
  std::vector<ResSEBlock> dec_joint_;
  std::vector<torch::nn::Linear> dec_code_;  // latent_injection "every_scale": z -> offsets
  // latent_injection "condition": z -> a map added to the condition's deepest one.
  torch::nn::Linear code_fc1{nullptr}, code_fc2{nullptr};
  std::vector<Upsample> dec_up_;
  ConvBlock head_tsdf{nullptr}, head_votes{nullptr};
  torch::nn::Conv3d out_tsdf{nullptr}, out_votes{nullptr};
  DerivedWeights heads_;  // both heads as one convolution, then one 1x1 (inference)
};
TORCH_MODULE(Cvae);

/// Every parameter and buffer of `model` by name (handles to the model's own tensors): what a
/// model file stores.
std::map<std::string, torch::Tensor> cvaeTensors(Cvae& model);

/// Rebuilds a model from a file written by saveCvae (offline/training/model_writer.h). Throws
/// std::runtime_error naming the file and the problem (missing, not a simstack model, config
/// invalid or not matching `expect`).
Cvae loadCvae(const std::string& path, const CvaeConfig* expect = nullptr,
              std::string* metadata = nullptr);

}  // namespace simstack
