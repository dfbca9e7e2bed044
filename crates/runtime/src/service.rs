//! The iceoryx2 service type of every insuwb process: iceoryx2 0.10's `ipc`
//! service with one change, the per-sample bookkeeping served from a pool.
//!
//! iceoryx2 0.10 wraps every loaned sample's bookkeeping (`ChunkMutSharedState`)
//! in its service's `ArcThreadSafetyPolicy`. For `ipc::Service` that policy
//! is `SingleThreaded`, an `Rc` made afresh for each loan: one heap
//! allocation per published sample, the only allocation left on a stage's
//! path. [`Ipc`] is the same service (every storage, connection, event and
//! naming type is `ipc::Service`'s, so its processes share the same files and
//! talk to `ipc::Service` processes) whose policy is [`Pooled`]: a
//! single-threaded reference count whose blocks are recycled through a
//! per-thread free list. After the first loans of each kind the free list
//! holds the blocks the steady state needs and a loan allocates nothing.

use core::alloc::Layout;
use core::cell::{Cell, RefCell};
use core::fmt::Debug;
use core::marker::PhantomData;
use core::ops::Deref;
use core::ptr::NonNull;

use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use iceoryx2_cal::arc_sync_policy::{ArcSyncPolicy, ArcSyncPolicyCreationError, LockGuard};
use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;
use iceoryx2_cal::{
    bag, dynamic_storage, event, hash, monitoring, reactor, resizable_shared_memory, serialize,
    shared_memory, static_storage, zero_copy_connection,
};

/// The service type of insuwb's ports: iceoryx2's `ipc::Service` with
/// [`Pooled`] as its thread-safety policy (see the module documentation).
/// Ports of this service are, as `ipc::Service`'s, neither `Send` nor `Sync`.
#[derive(Debug, Clone)]
pub struct Ipc {}

impl iceoryx2::service::Service for Ipc {
    type StaticStorage = static_storage::recommended::Ipc;
    type ConfigSerializer = serialize::recommended::Recommended;
    type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::PersistentIpc<T>;
    type Bag = bag::recommended::Recommended;
    type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<T>;
    type ServiceNameHasher = hash::recommended::Recommended;
    type SharedMemory = shared_memory::recommended::Ipc<PoolAllocator>;
    type ResizableSharedMemory = resizable_shared_memory::recommended::Ipc<PoolAllocator>;
    type Connection = zero_copy_connection::recommended::Ipc;
    type Event = event::recommended::Ipc;
    type Monitoring = monitoring::recommended::Ipc;
    type Reactor = reactor::recommended::Ipc;
    type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> = Pooled<T>;
    type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<KeyType>;
    type BlackboardPayload = shared_memory::recommended::Ipc<BumpAllocator>;
    type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
}

impl iceoryx2::service::internal::ServiceInternal<Ipc> for Ipc {}

/// Free blocks a thread keeps per block layout; more are returned to the heap.
/// A stage has at most a few samples of one kind on loan at a time.
pub const POOL_BLOCKS_PER_LAYOUT: usize = 64;

/// Distinct block layouts a thread's pool keeps (one per bookkeeping type
/// iceoryx2 wraps; blocks of further layouts go back to the heap).
const POOL_LAYOUTS: usize = 8;

/// A thread's free blocks, by layout.
struct FreeList {
    layout: Layout,
    blocks: Vec<NonNull<u8>>,
}

struct Pool {
    lists: Vec<FreeList>,
}

impl Pool {
    fn take(&mut self, layout: Layout) -> Option<NonNull<u8>> {
        self.lists
            .iter_mut()
            .find(|l| l.layout == layout)
            .and_then(|l| l.blocks.pop())
    }

    /// Keeps `block` for reuse; false when the pool is full for its layout.
    fn keep(&mut self, layout: Layout, block: NonNull<u8>) -> bool {
        if let Some(l) = self.lists.iter_mut().find(|l| l.layout == layout) {
            if l.blocks.len() < POOL_BLOCKS_PER_LAYOUT {
                l.blocks.push(block);
                return true;
            }
            return false;
        }
        if self.lists.len() >= POOL_LAYOUTS {
            return false;
        }
        let mut blocks = Vec::with_capacity(POOL_BLOCKS_PER_LAYOUT);
        blocks.push(block);
        self.lists.push(FreeList { layout, blocks });
        true
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        for l in &self.lists {
            for b in &l.blocks {
                // SAFETY: every kept block was allocated by the global
                // allocator with `l.layout` and is owned by the pool alone.
                #[allow(unsafe_code)]
                unsafe {
                    std::alloc::dealloc(b.as_ptr(), l.layout);
                }
            }
        }
    }
}

thread_local! {
    static POOL: RefCell<Pool> = RefCell::new(Pool {
        lists: Vec::with_capacity(POOL_LAYOUTS),
    });
}

/// Blocks allocated from the heap by [`Pooled::new`] on this thread (the pool
/// was empty for their layout): constant in a steady state.
#[must_use]
pub fn pool_misses() -> u64 {
    MISSES.with(Cell::get)
}

thread_local! {
    static MISSES: Cell<u64> = const { Cell::new(0) };
}

/// The block behind a [`Pooled`]: its reference count and value.
struct Inner<T> {
    strong: Cell<usize>,
    value: T,
}

/// A single-threaded reference-counted value whose block comes from, and
/// returns to, the creating thread's pool: the `ArcThreadSafetyPolicy` of
/// [`Ipc`]. Neither `Send` nor `Sync`, so it is created and dropped on one
/// thread, whose pool it uses.
pub struct Pooled<T: Send + Debug + Abandonable> {
    ptr: NonNull<Inner<T>>,
    _owns: PhantomData<Inner<T>>,
}

impl<T: Send + Debug + Abandonable> Pooled<T> {
    fn inner(&self) -> &Inner<T> {
        // SAFETY: `ptr` points to an initialised `Inner<T>` for as long as
        // any `Pooled` holding it lives (the count is at least 1).
        #[allow(unsafe_code)]
        unsafe {
            self.ptr.as_ref()
        }
    }
}

impl<T: Send + Debug + Abandonable> Debug for Pooled<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Pooled")
            .field("value", &self.inner().value)
            .finish()
    }
}

impl<T: Send + Debug + Abandonable> Clone for Pooled<T> {
    fn clone(&self) -> Self {
        let s = &self.inner().strong;
        s.set(s.get().saturating_add(1));
        Self {
            ptr: self.ptr,
            _owns: PhantomData,
        }
    }
}

impl<T: Send + Debug + Abandonable> Drop for Pooled<T> {
    fn drop(&mut self) {
        let s = &self.inner().strong;
        let left = s.get().saturating_sub(1);
        s.set(left);
        if left > 0 {
            return;
        }
        let layout = Layout::new::<Inner<T>>();
        // SAFETY: this was the last reference: the value is dropped once and
        // the block, allocated with `layout`, is then unused.
        #[allow(unsafe_code)]
        unsafe {
            core::ptr::drop_in_place(core::ptr::addr_of_mut!((*self.ptr.as_ptr()).value));
        }
        let block = self.ptr.cast::<u8>();
        let kept = POOL
            .try_with(|p| p.try_borrow_mut().is_ok_and(|mut p| p.keep(layout, block)))
            .unwrap_or(false);
        if !kept {
            // SAFETY: allocated by the global allocator with `layout`; no
            // reference to it remains.
            #[allow(unsafe_code)]
            unsafe {
                std::alloc::dealloc(block.as_ptr(), layout);
            }
        }
    }
}

impl<T: Send + Debug + Abandonable> Abandonable for Pooled<T> {
    #[allow(unsafe_code)]
    unsafe fn abandon_in_place(this: NonNull<Self>) {
        // As iceoryx2's `SingleThreaded`: the last reference abandons the
        // value (and leaks its block); another one only drops its count.
        // SAFETY: the caller hands over a valid `Pooled` it will not use again.
        unsafe {
            let this = this.as_ptr();
            let inner = (*this).ptr.as_ptr();
            if (*inner).strong.get() == 1 {
                T::abandon_in_place(NonNull::new_unchecked(core::ptr::addr_of_mut!(
                    (*inner).value
                )));
            } else {
                core::ptr::drop_in_place(this);
            }
        }
    }
}

/// Access to a [`Pooled`] value (single-threaded: no lock is taken).
#[derive(Debug)]
pub struct PooledGuard<'parent, T> {
    value: &'parent T,
}

impl<T> Deref for PooledGuard<'_, T> {
    type Target = T;

    fn deref(&self) -> &T {
        self.value
    }
}

impl<'parent, T: Send + Abandonable> LockGuard<'parent, T> for PooledGuard<'parent, T> {}

impl<T: Send + Debug + Abandonable> ArcSyncPolicy<T> for Pooled<T> {
    type LockGuard<'parent>
        = PooledGuard<'parent, T>
    where
        Self: 'parent,
        T: 'parent;

    fn new(value: T) -> Result<Self, ArcSyncPolicyCreationError> {
        let layout = Layout::new::<Inner<T>>();
        let pooled = POOL
            .try_with(|p| p.try_borrow_mut().ok().and_then(|mut p| p.take(layout)))
            .ok()
            .flatten();
        let block = match pooled {
            Some(b) => b,
            None => {
                let _ = MISSES.try_with(|m| m.set(m.get().saturating_add(1)));
                if layout.size() == 0 {
                    // Never: the count makes the block at least a word.
                    return Err(ArcSyncPolicyCreationError::InternalFailure);
                }
                // SAFETY: `layout` has a non-zero size.
                #[allow(unsafe_code)]
                let raw = unsafe { std::alloc::alloc(layout) };
                NonNull::new(raw).ok_or(ArcSyncPolicyCreationError::InsufficientResources)?
            }
        };
        let ptr = block.cast::<Inner<T>>();
        // SAFETY: `block` is an unused allocation of `Inner<T>`'s layout.
        #[allow(unsafe_code)]
        unsafe {
            ptr.as_ptr().write(Inner {
                strong: Cell::new(1),
                value,
            });
        }
        Ok(Self {
            ptr,
            _owns: PhantomData,
        })
    }

    fn lock(&self) -> Self::LockGuard<'_> {
        PooledGuard {
            value: &self.inner().value,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::rc::Rc;

    /// A value that counts its drops.
    #[derive(Debug)]
    struct Counted(Rc<Cell<u32>>);
    // The policy only stores the value; the test runs on one thread.
    #[allow(unsafe_code)]
    // SAFETY: never sent: the test holds it on one thread.
    unsafe impl Send for Counted {}
    impl Abandonable for Counted {
        #[allow(unsafe_code)]
        unsafe fn abandon_in_place(_this: NonNull<Self>) {}
    }
    impl Drop for Counted {
        fn drop(&mut self) {
            self.0.set(self.0.get() + 1);
        }
    }

    #[test]
    fn clones_share_the_value_and_the_last_drop_drops_it_once() {
        let drops = Rc::new(Cell::new(0));
        let a = Pooled::new(Counted(drops.clone())).unwrap();
        let b = a.clone();
        assert!(core::ptr::eq(&*a.lock(), &*b.lock()));
        drop(a);
        assert_eq!(drops.get(), 0);
        drop(b);
        assert_eq!(drops.get(), 1);
    }

    #[test]
    fn blocks_are_reused_after_the_first_allocation() {
        std::thread::spawn(|| {
            let drops = Rc::new(Cell::new(0));
            let first = Pooled::new(Counted(drops.clone())).unwrap();
            let second = Pooled::new(Counted(drops.clone())).unwrap();
            let misses = pool_misses();
            assert_eq!(misses, 2);
            drop(first);
            drop(second);
            for _ in 0..1000 {
                let a = Pooled::new(Counted(drops.clone())).unwrap();
                let b = Pooled::new(Counted(drops.clone())).unwrap();
                drop((a, b));
            }
            assert_eq!(pool_misses(), misses, "steady state took heap blocks");
            assert_eq!(drops.get(), 2002);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_full_pool_returns_blocks_to_the_heap() {
        std::thread::spawn(|| {
            let drops = Rc::new(Cell::new(0));
            let many: Vec<_> = (0..POOL_BLOCKS_PER_LAYOUT + 10)
                .map(|_| Pooled::new(Counted(drops.clone())).unwrap())
                .collect();
            drop(many);
            let before = pool_misses();
            let again: Vec<_> = (0..POOL_BLOCKS_PER_LAYOUT + 10)
                .map(|_| Pooled::new(Counted(drops.clone())).unwrap())
                .collect();
            assert_eq!(pool_misses() - before, 10);
            drop(again);
        })
        .join()
        .unwrap();
    }
}
