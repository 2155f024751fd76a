"""Layer 5: conversions between parameterisations and models. ``roughness`` (alpha <-> perceptual
roughness), ``phong`` (closed-form Phong/Blinn-Phong <-> Beckmann/GGX), ``phong_to_ggx`` (the
fitted Phong -> GGX study), ``gltf`` (export to a glTF 2.0 metallic-roughness material, exact or
fitted, with the Appendix B evaluator, documents and a reader), ``mitsuba`` (export to a Mitsuba 3
BSDF, verified by round trip through Mitsuba when it is installed: the ``mitsuba`` extra)."""
