"""World Models components: the VAE's ELBO terms and the MDN-RNN's mixture, against references."""
import math

import torch
import torch.distributions as D

from wmthesis.world_models.memory import Memory, Mixture, memory_loss, mixture_nll, sample_mixture
from wmthesis.world_models.vision import VAE, elbo_loss, frames_to_input, input_to_frames, kl_to_standard_normal


def test_kl_matches_torch_distributions():
    g = torch.Generator().manual_seed(0)
    mu, logvar = torch.randn(6, 16, generator=g), torch.randn(6, 16, generator=g)
    reference = D.kl_divergence(D.Normal(mu, (0.5 * logvar).exp()), D.Normal(0.0, 1.0)).sum(-1)
    assert torch.allclose(kl_to_standard_normal(mu, logvar), reference, atol=1e-5)


def test_vae_shapes_and_reconstruction_term_is_bernoulli_nll():
    torch.manual_seed(0)
    vae = VAE(latent_size=8)
    x = torch.rand(4, 3, 64, 64)
    logits, mu, logvar = vae(x)
    assert logits.shape == x.shape and mu.shape == logvar.shape == (4, 8)
    terms = elbo_loss(x, logits, mu, logvar)
    bernoulli = -(x * torch.log(torch.sigmoid(logits)) + (1 - x) * torch.log(1 - torch.sigmoid(logits)))
    assert torch.allclose(terms["reconstruction"], bernoulli.flatten(1).sum(1).mean(), rtol=1e-4)
    assert torch.allclose(terms["loss"], terms["reconstruction"] + terms["kl"])


def test_frame_conversion_round_trips():
    frames = torch.randint(0, 256, (2, 5, 64, 64, 3), dtype=torch.uint8)
    assert torch.equal(input_to_frames(frames_to_input(frames)), frames)


def random_mixture(shape=(4, 3), K=5, L=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return Mixture(torch.log_softmax(torch.randn(*shape, K, generator=g), -1),
                   torch.randn(*shape, K, L, generator=g), 0.5 * torch.randn(*shape, K, L, generator=g))


def test_mixture_nll_matches_mixture_same_family():
    mixture = random_mixture()
    target = torch.randn(4, 3, 16, generator=torch.Generator().manual_seed(1))
    reference = D.MixtureSameFamily(D.Categorical(logits=mixture.log_pi),
                                    D.Independent(D.Normal(mixture.mu, mixture.log_sigma.exp()), 1))
    assert torch.allclose(mixture_nll(mixture, target), -reference.log_prob(target), atol=1e-4)


def test_mixture_nll_is_stable_far_from_every_component():
    mixture = random_mixture()
    nll = mixture_nll(mixture, torch.full((4, 3, 16), 1e3))
    assert torch.isfinite(nll).all() and (nll > 1e4).all()


def test_sampling_with_temperature_scales_weights_and_spread():
    K, L = 2, 1
    mixture = Mixture(torch.log(torch.tensor([[0.8, 0.2]])).expand(20_000, K),
                      torch.tensor([[[-10.0], [10.0]]]).expand(20_000, K, L),
                      torch.zeros(20_000, K, L))
    g = torch.Generator().manual_seed(0)
    for tau in (1.0, 2.0):
        z = sample_mixture(mixture, tau, g)[:, 0]
        weights = torch.tensor([0.8, 0.2]) ** (1 / tau)
        assert abs((z > 0).float().mean() - weights[1] / weights.sum()) < 0.015
        assert abs((z[z < 0] + 10).std() - math.sqrt(tau)) < 0.05


def test_mdn_rnn_fits_a_known_mixture():
    """Next latents drawn from a fixed 2-component mixture that depends on the action."""
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    B, T, L = 64, 10, 2
    memory = Memory(L, n_actions=2, hidden_size=32, n_gaussians=2)
    optimiser = torch.optim.Adam(memory.parameters(), lr=1e-2)
    centres = torch.tensor([[-2.0, 0.0], [2.0, 0.0]])

    def batch():
        actions = torch.randint(0, 2, (B, T), generator=g)
        component = torch.randint(0, 2, (B, T), generator=g)
        next_z = centres[component] * (1 + 2 * actions[..., None]) + 0.1 * torch.randn(B, T, L, generator=g)
        return torch.zeros(B, T, L), actions, next_z

    for _ in range(300):
        z, actions, next_z = batch()
        terms = memory_loss(memory(z, actions), next_z, torch.zeros(B, T), torch.zeros(B, T))
        optimiser.zero_grad()
        terms["loss"].backward()
        optimiser.step()
    z, actions, next_z = batch()
    nll = mixture_nll(memory(z, actions).next_latent, next_z).mean()
    # The true conditional density: two equal Gaussians of std 0.1 in 2-D, well separated.
    true_nll = -math.log(0.5) + 2 * (math.log(0.1) + 0.5 * math.log(2 * math.pi)) + 1.0
    assert nll < true_nll + 0.3, (nll, true_nll)


def test_the_seed_curves_figure_draws_every_seed_by_agent_steps():
    import matplotlib
    matplotlib.use("Agg")
    from wmthesis.world_models.figures import plot_seed_curves

    curve = lambda shift: [{"generation": g, "mean": g + shift, "best": g + shift + 5, "agent_steps": 1000 * g,  # noqa: E731
                            **({"eval_return": g + shift, "eval_std": 1.0} if g % 2 == 0 else {})}
                           for g in range(1, 5)]
    fig = plot_seed_curves({0: curve(0), 1: curve(-10)}, human=12.1, thesis=18)
    left, right = fig.axes
    assert len(left.lines) == 2 * 2 + 2  # mean and best per seed, two reference lines
    assert list(left.lines[0].get_xdata()) == [0.001, 0.002, 0.003, 0.004]
    assert [list(line.get_ydata()) for line in right.lines[:2]] == [[2, 4], [-8, -6]]
