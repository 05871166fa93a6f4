"""The learning kit: what every learner (system identification, end-to-end learning, the imitation learners to
come) is built from: models, datasets, the training loop, checkpoints, evaluation (README.md in this folder)."""
