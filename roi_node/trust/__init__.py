"""Signed sessions, ROI bags and datasets (OpenSSF model-signing), their verification, and the sharing policy."""
