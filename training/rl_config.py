"""The RL jobs' settings, apart from training.rl so that the command line and the core install
(no torch, no stable-baselines3) can read them."""

RL_EXTRA_MISSING = (
    "RL training and policies need torch and stable-baselines3: pip install torch (a CPU build "
    "first, e.g. torch==2.13.0, or pip pulls a CUDA one), then pip install 'fourwis[rl]'"
)

ALGOS = ("ppo", "sac", "td3")
ALGO_CONFIGS: dict[str, dict] = {
    # on-policy: 16 cars x 256 steps (5 s each) per update, 10 epochs of minibatches of 1024
    "ppo": {
        "n_steps": 256,
        "batch_size": 1024,
        "n_epochs": 10,
        "learning_rate": 3e-4,
        "gamma": 0.99,
        "gae_lambda": 0.95,
        "clip_range": 0.2,
        "ent_coef": 0.0,
        "policy_kwargs": {"net_arch": [128, 128]},
    },
    # off-policy: one gradient step per vector step (16 env steps), replay of 200k transitions
    "sac": {
        "buffer_size": 200_000,
        "learning_starts": 2_000,
        "batch_size": 256,
        "learning_rate": 3e-4,
        "gamma": 0.99,
        "tau": 0.005,
        "train_freq": 1,
        "gradient_steps": 1,
        "policy_kwargs": {"net_arch": [128, 128]},
    },
    "td3": {
        "buffer_size": 200_000,
        "learning_starts": 2_000,
        "batch_size": 256,
        "learning_rate": 1e-3,
        "gamma": 0.99,
        "tau": 0.005,
        "train_freq": 1,
        "gradient_steps": 1,
        "action_noise_std": 0.1,
        "policy_kwargs": {"net_arch": [128, 128]},
    },
}
EVAL_SCENARIO = "sine_with_dwell"  #: held out: never drawn by the "random" training distribution
