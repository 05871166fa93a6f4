"""The learning kit: what every learner (system identification, end-to-end learning, the imitation learners to
come) is built from. See README.md in this folder.

    from myriad.runtime.learn.models import make_model          # the one registry of model names
    from myriad.runtime.learn.loop import Stop, train           # the one training loop and its stop reasons
"""
