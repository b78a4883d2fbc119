"""Normal contact force laws (docs/physics/contact.md)."""
