"""The simulated robot: task scenes (MuJoCo model of FR3, tool and task objects), the workspace
box and task-plane projection, and the mink differential IK."""
