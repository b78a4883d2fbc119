"""Normal contact force laws (physics.md section 2)."""
