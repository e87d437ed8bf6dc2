"""armbench reports package."""
