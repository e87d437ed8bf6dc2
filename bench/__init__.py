"""armbench bench package."""
