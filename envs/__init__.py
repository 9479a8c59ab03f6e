"""Truth plant, road, sensors, scenarios, the closed loop and the Gymnasium environments of
fourwis (``fourwis.envs``). Its modules are imported on use: ``import fourwis`` registers the
environment without loading the plant."""

#: gymnasium's TimeLimit for gym.make: 30 s at the default 20 ms control step, beyond every
#: scenario's default duration (the longest, paper_split_dlc, runs 27.4 s); episodes end at
#: their scenario's end (tests/test_gym_env.py checks the durations)
MAX_EPISODE_STEPS = 1500
