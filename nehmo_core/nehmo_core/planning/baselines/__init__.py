"""The paper's baselines and peers: naive and reckless planners, CHOMP, OMPL."""
