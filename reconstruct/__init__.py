"""loggrasp reconstruct package."""
