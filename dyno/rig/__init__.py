"""The rig's description: rig.toml read and checked, its ambient, inertia and input-torque sections."""
