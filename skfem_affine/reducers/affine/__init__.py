"""reducers/affine."""
