"""The F1/10 car with LiDAR under adversarial noise (paper, section 5.2 and Appendix B)."""
