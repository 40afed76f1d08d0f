/** The on-device CRF tracker: pure functions and classes over typed arrays (no DOM, no map). */
export * from "./npz";
export * from "./model";
export * from "./sensors";
export * from "./filters";
export * from "./fingerprints";
export * from "./tracker";
export * from "./live";
export * from "./evaluate";
export * from "./modes";
