//! What the `stills` and `scene` sources draw, apart from the stages that run them: the motions
//! of a window (`motion.rs`: shake paths, pans, cut-out objects, rotation, zoom; `hand.rs`:
//! hand-held shake; `sprite.rs`: the cut-outs), the synthetic
//! scenes of the paper's figures (`scene.rs`), sampling and textures (`texture.rs`). Depends on
//! nothing above it (no stage, no command).

pub mod hand;
pub mod motion;
pub mod scene;
pub mod sprite;
pub mod texture;
