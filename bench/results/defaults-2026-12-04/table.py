import csv,glob,collections,sys
d=sys.argv[1]
data=collections.defaultdict(dict)
for f in sorted(glob.glob(d+'/*.csv')):
    for r in csv.DictReader(open(f)):
        key=(r['backend'],f.split('/')[-1][:-4],r['ray_kind'],r['query'])
        data[key][(r['layout'],r['traversal'])]=float(r['mrays_per_s'])
choice={('cpu-avx512','closest'):('mbvh8','stack-ordered'),('cpu-avx512','any'):('mbvh8','bitstack'),('cpu-avx2','closest'):('mbvh8','stack-ordered'),('cpu-avx2','any'):('mbvh8','bitstack'),('cpu-scalar','closest'):('mbvh4','stack-ordered'),('cpu-scalar','any'):('mbvh4','stack-ordered')}
agg=collections.defaultdict(list)
for key,v in sorted(data.items()):
    b,s,k,q=key
    if (q=='any')!=(k=='shadow'): continue
    c=choice[(b,q)]; best=max(v,key=v.get)
    agg[(b,q)].append((v[c]/v[best],s,k,best))
for (b,q),l in sorted(agg.items()):
    r=[x[0] for x in l]
    worst=min(l)
    print('%-11s %-8s rows %d mean %.3f worst %.3f (%s %s, best %s/%s) within5 %d'%(b,q,len(r),sum(r)/len(r),worst[0],worst[1],worst[2],worst[3][0],worst[3][1],sum(x>=0.95 for x in r)))
