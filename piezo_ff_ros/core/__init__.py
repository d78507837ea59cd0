"""The ROS-free core: models, compensators, synthesis, identification, metrics, recording, diagnosis."""
