"""Layer 5: conversions between parameterisations and models. ``roughness`` (alpha <-> perceptual
roughness), ``phong`` (closed-form Phong/Blinn-Phong <-> Beckmann/GGX), ``phong_to_ggx`` (the
fitted Phong -> GGX study)."""
