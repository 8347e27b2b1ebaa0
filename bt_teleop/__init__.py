"""bt_teleop: the browser teleoperation app (viser + MuJoCo + mink). Filled by issue 4."""
