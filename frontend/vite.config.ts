/// <reference types="vitest/config" />
import { defineConfig } from "vite";

// The built assets are served by the FastAPI server at "/"; during `npm run dev` the
// API is proxied to a local `posefix serve`.
export default defineConfig({
  base: "/",
  build: { outDir: "dist", sourcemap: true, chunkSizeWarningLimit: 1500 },
  server: {
    proxy: {
      "/api": process.env.POSEFIX_API ?? "http://127.0.0.1:8000",
    },
  },
  test: {
    include: ["tests/**/*.test.ts"],
    environment: "node",
  },
});
