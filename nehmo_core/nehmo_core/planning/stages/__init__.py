"""What NeHMO adds to the paper's Opt, one mechanism per module (each off in the paper preset)."""
