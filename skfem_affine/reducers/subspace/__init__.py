"""reducers/subspace."""
