"""Model-based 2D/3D tracking: bone models, registration, whole-trial tracking, kinematics."""
