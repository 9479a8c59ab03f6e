"""Asymmetric actor-critic policies for stable-baselines3 (Pinto et al. 2018, "Asymmetric
Actor Critic for Image-Based Robot Learning", RSS): the critic learns from the true state, the
actor acts on the estimate alone.

With ``privileged=True`` the env's observation is the agent's N_OBS slots followed by the
truth's N_OBS (:class:`envs.gym_env.YawStabilityEnv`). These policies read all 2 N_OBS slots
in the critic (PPO's value network; SAC's and TD3's Q-networks) and only the first N_OBS in
the actor, so a trained actor needs no truth: :class:`training.rl.PolicyController` runs it on
the estimate. ``training.rl.train`` picks them for a privileged env (:data:`POLICIES`).
"""

from __future__ import annotations

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, MlpExtractor
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy
from torch import nn

from fourwis.envs.gym_env import N_OBS


class AgentObservation(BaseFeaturesExtractor):
    """The agent's slots (the first N_OBS) of a privileged observation: the actors' features."""

    def __init__(self, observation_space: spaces.Box):
        if observation_space.shape != (2 * N_OBS,):
            raise ValueError(
                f"an asymmetric policy needs the privileged observation of shape ({2 * N_OBS},) "
                f"(env_kwargs privileged=True), got {observation_space.shape}"
            )
        super().__init__(observation_space, N_OBS)

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return observations[..., :N_OBS]


class AsymmetricMlpExtractor(nn.Module):
    """SB3's MlpExtractor with the policy network on the agent's slots and the value network on
    all of them (same ``net_arch`` for both)."""

    def __init__(self, feature_dim: int, net_arch, activation_fn: type[nn.Module], device: th.device | str):
        super().__init__()
        if feature_dim != 2 * N_OBS:
            raise ValueError(
                f"an asymmetric policy needs the privileged observation of {2 * N_OBS} features "
                f"(env_kwargs privileged=True), got {feature_dim}"
            )
        actor = MlpExtractor(N_OBS, net_arch, activation_fn, device)
        critic = MlpExtractor(feature_dim, net_arch, activation_fn, device)
        self.policy_net, self.value_net = actor.policy_net, critic.value_net
        self.latent_dim_pi, self.latent_dim_vf = actor.latent_dim_pi, critic.latent_dim_vf

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return self.policy_net(features[..., :N_OBS])

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        return self.value_net(features)


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """PPO's policy: actor on the agent's slots, value function on the whole observation."""

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = AsymmetricMlpExtractor(self.features_dim, self.net_arch, self.activation_fn, self.device)


class AsymmetricSACPolicy(SACPolicy):
    """SAC's policy: actor on the agent's slots, Q-networks on the whole observation."""

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None):
        return super().make_actor(_actor_features(self))


class AsymmetricTD3Policy(TD3Policy):
    """TD3's policy: actor (and its target) on the agent's slots, Q-networks on the whole
    observation."""

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None):
        return super().make_actor(_actor_features(self))


def _actor_features(policy: SACPolicy | TD3Policy) -> AgentObservation:
    """A fresh agent-slot extractor for an off-policy actor (whose critic, with a shared
    extractor, would see the agent's slots only: refused)."""
    if policy.share_features_extractor:
        raise ValueError(
            "an asymmetric policy cannot share the actor's features extractor with the critic "
            "(policy_kwargs share_features_extractor=False)"
        )
    return AgentObservation(policy.observation_space)


#: the asymmetric policy of each algorithm of training.rl.ALGOS
POLICIES = {"ppo": AsymmetricActorCriticPolicy, "sac": AsymmetricSACPolicy, "td3": AsymmetricTD3Policy}
