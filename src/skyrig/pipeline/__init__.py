"""Layer 3: stages over a project folder (demo project, later the full processing chain)."""
