/** A tiny observable store: holds one immutable value, notifies subscribers on change. */
export type Listener<T> = (next: T, prev: T) => void;

export class Store<T> {
  private value: T;
  private listeners = new Set<Listener<T>>();

  constructor(initial: T) {
    this.value = initial;
  }

  get(): T {
    return this.value;
  }

  /** Replace the value with `fn(value)`; listeners run only if it changed. */
  update(fn: (s: T) => T): void {
    const prev = this.value;
    const next = fn(prev);
    if (next === prev) return;
    this.value = next;
    for (const l of [...this.listeners]) l(next, prev);
  }

  subscribe(l: Listener<T>): () => void {
    this.listeners.add(l);
    return () => this.listeners.delete(l);
  }
}
