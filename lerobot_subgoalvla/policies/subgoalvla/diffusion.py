"""Diffusion objective and sampler shared by the planner and the generator (paper eqs. 3-4, appendix B).

The denoiser is any network ``f(x_noisy, timesteps, cond, cond_mask, drop_cond) -> eps_hat`` (``dit.DiT``);
this
module owns everything about noise: the schedule, the training loss and DDIM sampling with classifier-free
guidance (style guide convention 4). The schedules are diffusers' own: ``DDPMScheduler`` for the forward
process ``x_i = sqrt(abar_i) x_0 + sqrt(1 - abar_i) eps`` (eq. 3/4 notation) and ``DDIMScheduler`` for
sampling, both with the squared-cosine alpha-bar schedule (``beta_schedule="squaredcos_cap_v2"``, tables 6-7).

Choices where the paper is loose (also in docs/model.md):
- Loss (appendix B.1): "timestep-weighted MSE between predicted and true noise (weighted by 1 - t/T), together
  with a small l2 regularisation (lambda = 0.001) on predictions". We use ``mean_i[(1 - t_i/T) * mse_i] +
  lambda * mean(eps_hat^2)`` with ``t_i`` in ``[0, T-1]`` (so the noisiest step keeps weight ``1/T`` > 0).
- "Repeated diffusion steps 8" (table 8): each sample is repeated ``R`` times with independent timesteps and
  noise, so one expensive backbone pass feeds ``R`` cheap denoiser passes.
- Label dropout p = 0.1 is drawn per repeated sample; the DiT swaps the condition for its learned null token.
- DDIM with 10 steps but only 8 training timesteps (appendix B.2 vs tables 6-7): DDIM can only visit timesteps
  that exist, so ``num_inference_steps > num_train_timesteps`` is an error, here as in the config (which
  rejects it first, with the flag names). The default walks every one of the 8 training timesteps once
  (docs/model.md has the measurement behind T = 8; T = 100 with DDIM 10 is the other reading, one flag each).
- Clipping: the 8-step squared-cosine schedule ends at alpha_bar_7 = 3.7e-5, so DDIM's first estimate of the
  clean sample, ``(x - sqrt(1 - abar) eps_hat) / sqrt(abar)``, multiplies the noise-prediction error by 163
  and the walk diverges (a tiny model's samples reach 1e4). The sampler therefore clips that estimate to
  ``[-clip_sample_range, clip_sample_range]`` (diffusers' ``clip_sample``), the bound of the normalised
  targets (1 for min/max-normalised actions, as LeRobot's Diffusion Policy does). ``None`` disables clipping.

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``R`` repeats, ``T`` tokens (trace steps or
action steps), ``X`` token features, ``Tc`` conditioning tokens, ``Dc`` conditioning width.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from diffusers import DDIMScheduler, DDPMScheduler
from einops import repeat
from torch import Tensor

#: What the objective needs from a network (``dit.DiT`` is one):
#: ``denoiser(x_noisy (B, T, X), timesteps (B,), cond (B, Tc, Dc), cond_mask (B, Tc) | None,
#: drop_cond (B,) | None) -> eps_hat (B, T, X)``.
Denoiser = Callable[[Tensor, Tensor, Tensor, Tensor | None, Tensor | None], Tensor]


class DiffusionObjective:
    """Noise schedule, training loss and guided DDIM sampler for one diffusion head.

    Args:
        num_train_timesteps: T, diffusion steps of the forward process
        (``DiTHeadConfig.num_train_timesteps``).
        num_inference_steps: DDIM steps at inference, at most T (``DiTHeadConfig.num_inference_steps``).
        beta_schedule: diffusers beta schedule name; "squaredcos_cap_v2" is the squared-cosine alpha-bar
            schedule.
        guidance_scale: classifier-free guidance scale s (1.0 = purely conditional, no extra forward pass).
        repeats: R, repeated diffusion steps per sample in training (8 in table 8).
        l2_weight: lambda of the l2 penalty on predictions (0.001 in appendix B.1).
        cond_dropout_prob: label dropout probability for classifier-free guidance (0.1 in appendix B.1).
        clip_sample_range: DDIM clips its clean-sample estimate to +-this (normalised units); None = no
            clipping.
    """

    def __init__(
        self,
        *,
        num_train_timesteps: int,
        num_inference_steps: int,
        beta_schedule: str = "squaredcos_cap_v2",
        guidance_scale: float = 1.0,
        repeats: int = 8,
        l2_weight: float = 1e-3,
        cond_dropout_prob: float = 0.1,
        clip_sample_range: float | None = 1.0,
    ) -> None:
        if repeats < 1:
            raise ValueError(f"repeats must be >= 1 (repeated diffusion steps per sample), got {repeats}")
        if not 0.0 <= cond_dropout_prob < 1.0:
            raise ValueError(f"cond_dropout_prob must be in [0, 1), got {cond_dropout_prob}")
        self.noise_scheduler = DDPMScheduler(
            num_train_timesteps=num_train_timesteps,
            beta_schedule=beta_schedule,
            clip_sample=False,
            prediction_type="epsilon",
        )
        # "trailing" spacing starts every DDIM walk at the noisiest timestep T-1 (pure noise is where sampling
        # starts), also when fewer steps than timesteps are taken.
        self.sampler = DDIMScheduler.from_config(
            self.noise_scheduler.config,
            set_alpha_to_one=True,
            timestep_spacing="trailing",
            clip_sample=clip_sample_range is not None,
            clip_sample_range=1.0 if clip_sample_range is None else clip_sample_range,
        )
        self.num_train_timesteps = num_train_timesteps
        self.num_inference_steps = self.checked_inference_steps(num_inference_steps)
        self.guidance_scale = guidance_scale
        self.repeats = repeats
        self.l2_weight = l2_weight
        self.cond_dropout_prob = cond_dropout_prob

    def checked_inference_steps(self, steps: int) -> int:
        """``steps`` if DDIM can take that many steps (1..T); raises ValueError otherwise."""
        if not 1 <= steps <= self.num_train_timesteps:
            raise ValueError(
                f"num_inference_steps={steps} must be in [1, num_train_timesteps={self.num_train_timesteps}] "
                "(DDIM skips training timesteps, it cannot add any)"
            )
        return steps

    def compute_loss(
        self,
        denoiser: Denoiser,
        x0: Tensor,
        cond: Tensor,
        cond_mask: Tensor | None = None,
        valid_mask: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """Timestep-weighted epsilon-MSE with repeated diffusion steps, l2 penalty and label dropout.

        Args:
            denoiser: the noise-prediction network.
            x0: (B, T, X) clean targets (trace G or action chunk A), already normalised.
            cond: (B, Tc, Dc) conditioning features.
            cond_mask: (B, Tc) bool, True = valid conditioning token.
            valid_mask: (B, T) bool, True = this target step counts (False for padded actions).
            generator: RNG for timesteps, noise and label dropout (None = global RNG).

        Returns:
            Scalar loss.
        """
        r, device = self.repeats, x0.device
        x0 = repeat(x0, "b t x -> (r b) t x", r=r)  # (R*B, T, X)
        cond = repeat(cond, "b s d -> (r b) s d", r=r)  # (R*B, Tc, Dc)
        cond_mask = None if cond_mask is None else repeat(cond_mask, "b s -> (r b) s", r=r)
        n = x0.shape[0]
        timesteps = torch.randint(0, self.num_train_timesteps, (n,), device=device, generator=generator)
        noise = torch.randn(x0.shape, device=device, dtype=x0.dtype, generator=generator)
        drop = torch.rand(n, device=device, generator=generator) < self.cond_dropout_prob
        x_noisy = self.noise_scheduler.add_noise(x0, noise, timesteps)
        pred = denoiser(x_noisy, timesteps, cond, cond_mask, drop)  # (R*B, T, X)
        sq_err = (pred - noise).pow(2)  # (R*B, T, X)
        if valid_mask is None:
            per_sample = sq_err.mean(dim=(1, 2))  # (R*B,)
        else:
            weights = repeat(valid_mask, "b t -> (r b) t 1", r=r).to(sq_err.dtype)  # (R*B, T, 1)
            per_sample = (sq_err * weights).sum(dim=(1, 2)) / (
                weights.sum(dim=(1, 2)) * sq_err.shape[-1]
            ).clamp_min(1)
        step_weight = 1.0 - timesteps.to(sq_err.dtype) / self.num_train_timesteps  # (R*B,) in (0, 1]
        return (step_weight * per_sample).mean() + self.l2_weight * pred.pow(2).mean()

    def guided_noise(
        self,
        denoiser: Denoiser,
        x: Tensor,
        timestep: Tensor,
        cond: Tensor,
        cond_mask: Tensor | None,
        guidance_scale: float,
    ) -> Tensor:
        """Classifier-free guidance ``eps_u + s (eps_c - eps_u)`` from ONE batched forward of both branches.

        Args:
            x: (B, T, X) current sample; timestep: () or (B,) step; cond (B, Tc, Dc); cond_mask (B, Tc) or
                None.

        Returns:
            (B, T, X) guided noise prediction.
        """
        b = x.shape[0]
        timesteps = timestep.expand(b).to(x.device) if timestep.ndim == 0 else timestep
        drop = torch.cat([torch.zeros(b, dtype=torch.bool), torch.ones(b, dtype=torch.bool)]).to(x.device)
        mask2 = None if cond_mask is None else torch.cat([cond_mask, cond_mask])
        eps = denoiser(
            torch.cat([x, x]), torch.cat([timesteps, timesteps]), torch.cat([cond, cond]), mask2, drop
        )
        eps_cond, eps_uncond = eps.chunk(2)
        return eps_uncond + guidance_scale * (eps_cond - eps_uncond)

    @torch.no_grad()
    def sample(
        self,
        denoiser: Denoiser,
        shape: tuple[int, int, int],
        cond: Tensor,
        cond_mask: Tensor | None = None,
        num_inference_steps: int | None = None,
        guidance_scale: float | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """DDIM (eta = 0) from Gaussian noise, with classifier-free guidance when ``guidance_scale != 1``.

        Args:
            denoiser: the noise-prediction network.
            shape: (B, T, X) of the sample.
            cond: (B, Tc, Dc) conditioning features; cond_mask (B, Tc) bool or None.
            num_inference_steps: DDIM steps, at most T (default: the objective's).
            guidance_scale: CFG scale s (default: the objective's).
            generator: RNG for the initial noise (None = global RNG).

        Returns:
            (B, T, X) denoised sample in the normalised space.
        """
        steps = (
            self.num_inference_steps
            if num_inference_steps is None
            else self.checked_inference_steps(num_inference_steps)
        )
        scale = self.guidance_scale if guidance_scale is None else guidance_scale
        x = torch.randn(shape, device=cond.device, dtype=cond.dtype, generator=generator)
        self.sampler.set_timesteps(steps, device=cond.device)
        for t in self.sampler.timesteps:
            if scale == 1.0:
                eps = denoiser(x, t.expand(shape[0]), cond, cond_mask, None)
            else:
                eps = self.guided_noise(denoiser, x, t, cond, cond_mask, scale)
            x = self.sampler.step(eps, t, x).prev_sample
        return x
