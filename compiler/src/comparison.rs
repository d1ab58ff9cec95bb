//! Speed against error: full-order references and the reduced runtime on one scene.
