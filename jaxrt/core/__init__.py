"""The foundation every stage builds on: float-exact vector helpers and autodiff rules."""
