"""Classical and state-space designs, gain tuning and co-design."""
