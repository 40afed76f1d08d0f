/** What every page gets from the application shell: the signed-in user and navigation. */
import type { UserPublic } from "../api/endpoints";

export interface AppContext {
  user: UserPublic | null;
  setUser(u: UserPublic | null): void;
  navigate(hash: string): void;
}
