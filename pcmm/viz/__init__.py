"""The views of a recorded run: the meshcat replay and its page, and the paper's figures.  They
read a run's record alone (its series, events and the URDF text it recorded), never a scene or
a model, so a saved run replays and plots on a machine without Pinocchio."""
